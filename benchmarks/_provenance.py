"""Where a results file came from: the xcalib version and git commit that wrote it (issue 25 item 6).

Every benchmark stores ``provenance()`` in the JSON it writes (``bench_calibration.write_result``
does it for the scripts that use it), so a reader can tell which code produced a figure and
``tests/test_results_fresh.py`` can say since when a file is stale.
"""

from __future__ import annotations

import datetime as _dt
import re
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
BASE_050 = "v0.5.0"  # the 0.5.0 release (lightweight tag on 4d6cc5d)
BASE_050_COMMIT = "4d6cc5d"  # the same commit, for clones without the tag


def _git(*args: str) -> str | None:
    try:
        p = subprocess.run(["git", "-C", str(REPO), *args], capture_output=True, text=True, timeout=20)
    except (OSError, subprocess.SubprocessError):
        return None
    return p.stdout.strip() if p.returncode == 0 else None


def git_head() -> str | None:
    """Short hash of HEAD, or None outside a git checkout."""
    return _git("rev-parse", "--short", "HEAD")


def base_050() -> str:
    """The ref of 0.5.0 as released: the ``v0.5.0`` tag where the clone has it, else its commit."""
    return BASE_050 if _git("rev-parse", "-q", "--verify", f"refs/tags/{BASE_050}") else BASE_050_COMMIT


def provenance(argv: list[str] | None = None) -> dict:
    """``{"xcalib": version, "git_commit": short HEAD, "git_dirty": bool, "date_utc": ISO time,
    "command": the command line}`` of the running benchmark. ``git_dirty`` counts changes under
    ``src/`` only (a benchmark rewriting its results file does not make the code dirty)."""
    m = re.search(r'__version__\s*=\s*"([^"]+)"', (REPO / "src" / "xcalib" / "_version.py").read_text())
    version = m.group(1) if m else None
    status = _git("status", "--porcelain", "--", "src")
    args = sys.argv if argv is None else ["benchmarks/" + Path(sys.argv[0]).name, *argv]
    return {"xcalib": version, "git_commit": git_head(), "git_dirty": None if status is None else bool(status),
            "date_utc": _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ"),
            "command": " ".join(str(a) for a in args)}
