"""``python -m xcalib.cli``: the ``xcalib`` command (without the console script on PATH)."""

from . import run

if __name__ == "__main__":
    run()
