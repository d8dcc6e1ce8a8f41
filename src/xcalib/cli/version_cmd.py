"""``xcalib version``."""

from __future__ import annotations

import json

import typer


def register(app: typer.Typer) -> None:
    @app.command("version", help="Print the package and input-protocol versions.\n\nExample: xcalib version --json")
    def version(as_json: bool = typer.Option(False, "--json", help="Machine-readable output.")) -> None:
        from .. import __version__
        from ..protocol import PROTOCOL_VERSION

        if as_json:
            typer.echo(json.dumps({"xcalib": __version__, "protocol": PROTOCOL_VERSION}))
        else:
            typer.echo(f"xcalib {__version__} (input protocol v{PROTOCOL_VERSION})")
