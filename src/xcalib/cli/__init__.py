"""The ``xcalib`` command line (typer + rich).

Each command lives in its own module exposing ``register(app)``, declared in the ``xcalib.commands``
entry-point group (:mod:`xcalib.plugins`; xcalib's own in ``pyproject.toml``, a third party's in
its own package): adding a command is one module and no edit here. Heavy
imports (torch, h5py, ...) happen inside the command functions so ``xcalib --help`` stays fast.
Exit codes: 0 success, 1 failure, 2 usage error.
"""

from __future__ import annotations

import logging
import sys

import typer

app = typer.Typer(
    name="xcalib",
    help="Camera-LiDAR matching and targetless extrinsic calibration.\n\n"
         "Example: xcalib demo --out xcalib-demo   (a synthetic site end to end, then the A9 sample when "
         "../shared/data/a9_sample exists; each command's --help shows its own example; docs/cli.md)",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)

#: Where xcalib's own commands come first in --help (an ordering only: every declared command is
#: registered, listed here or not).
_HELP_ORDER = ["demo", "match", "calibrate", "calibrate-many", "detect", "bootstrap", "train", "validate", "export", "synth", "cache",
               "convert", "bag", "monitor", "version", "reference"]


def _load_commands() -> list[str]:
    """Register every ``xcalib.commands`` entry point; returns the names registered. A module
    without ``register(app)`` or one that fails to import is reported by name (PluginWarning)."""
    from ..plugins import PluginWarning
    from ..plugins import entries as plugin_entries
    from ..plugins import load as load_plugin

    order = {n: i for i, n in enumerate(_HELP_ORDER)}
    done = []
    for entry in sorted(plugin_entries("xcalib.commands"), key=lambda e: (order.get(e.name, len(order)), e.name)):
        mod = load_plugin(entry)
        if mod is None:
            continue
        register = getattr(mod, "register", None)
        if not callable(register):
            import warnings

            warnings.warn(f"xcalib plugin {entry.name!r} ({entry.value!r}, from {entry.dist}) has no "
                          "register(app) function; command not added", PluginWarning, stacklevel=2)
            continue
        register(app)
        done.append(entry.name)
    return done




def _print_version(value: bool) -> None:
    """``xcalib --version``: what ``xcalib version`` prints, then exit 0."""
    if value:
        from .. import __version__
        from ..protocol import PROTOCOL_VERSION

        typer.echo(f"xcalib {__version__} (input protocol v{PROTOCOL_VERSION})")
        raise typer.Exit(0)


@app.callback()
def _root(version: bool = typer.Option(False, "--version", is_eager=True, callback=_print_version,
                                       help="Print the package and input-protocol versions and exit.")) -> None:
    """Camera-LiDAR matching and targetless extrinsic calibration."""


COMMANDS = _load_commands()


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
