"""Package-level behaviour: cheap import, lazy exports, CLI exit codes."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

import xcalib
from xcalib.cli import main


def test_import_does_not_import_torch():
    code = "import sys, xcalib; xcalib.validate_frame_inputs; print('torch' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


def test_protocol_version_is_exported():
    assert xcalib.PROTOCOL_VERSION == "1.0"
    assert issubclass(xcalib.ProtocolError, ValueError)


def test_unknown_attribute_raises_attribute_error():
    with pytest.raises(AttributeError, match="no attribute"):
        xcalib.does_not_exist  # noqa: B018


def test_cli_version_json(capsys):
    assert main(["version", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out == {"xcalib": xcalib.__version__, "protocol": "1.0"}


def test_cli_unknown_command_is_usage_error():
    assert main(["no-such-command"]) == 2
