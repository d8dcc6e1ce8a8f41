"""The ``xcalib`` command line (typer + rich).

Each command lives in its own module ``xcalib.cli.<name>`` exposing ``register(app)``; heavy
imports (torch, h5py, ...) happen inside the command functions so ``xcalib --help`` stays fast.
Exit codes: 0 success, 1 failure, 2 usage error.
"""

from __future__ import annotations

import importlib
import importlib.util
import logging
import sys

import typer

app = typer.Typer(
    name="xcalib",
    help="Camera-LiDAR matching and targetless extrinsic calibration.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)

# Order = order in --help.
_COMMAND_MODULES = [
    "demo", "match", "calibrate", "calibrate_many", "bootstrap", "train", "validate", "export", "synth", "cache",
    "convert", "bag", "version", "reference",
]


def _load_commands() -> None:
    for name in _COMMAND_MODULES:
        modname = f"xcalib.cli.{name}_cmd"
        if importlib.util.find_spec(modname) is None:
            continue
        importlib.import_module(modname).register(app)




@app.callback()
def _root() -> None:
    """Camera-LiDAR matching and targetless extrinsic calibration."""


_load_commands()


def main(argv: list[str] | None = None) -> int:
    """Console entry point: run the app and map failures to exit codes (1 failure, 2 usage)."""
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    try:
        # with standalone_mode=False click returns the code of a raised typer.Exit instead of exiting
        rv = app(args=argv, standalone_mode=False)
        if isinstance(rv, int):
            return rv
    except SystemExit as exc:  # typer/click exits
        code = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
        return code
    except KeyboardInterrupt:
        return 130
    except Exception as exc:  # noqa: BLE001 - the CLI reports every failure the same way
        # click's own exceptions (vendored by typer) carry an exit_code: usage errors are 2
        if hasattr(exc, "exit_code") and hasattr(exc, "show"):
            exc.show()
            return int(exc.exit_code)
        if hasattr(exc, "exit_code"):
            return int(exc.exit_code)
        if type(exc).__name__ == "Abort":
            return 1
        typer.echo(f"error: {exc}", err=True)
        if logging.getLogger().isEnabledFor(logging.DEBUG):
            raise
        return 1
    return 0


def run() -> None:  # pragma: no cover
    sys.exit(main())
