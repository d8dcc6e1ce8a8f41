"""Extensions as a third party ships them: a package on sys.path with a ``*.dist-info/entry_points.txt``
adds a frame source and a command with zero edits to xcalib; a broken plugin is reported by name
(issue 28)."""

from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from xcalib.plugins import GROUPS, entries

SOURCE = textwrap.dedent('''
    """A frame source for folders holding a ``dets.csv`` (one synthetic frame per row)."""
    from pathlib import Path

    from xcalib.io.sources import register_source


    def _detect(path: Path) -> bool:
        return path.is_dir() and (path / "dets.csv").is_file()


    def _open(path: Path, *, camera=None, **options):
        from xcalib.data.synth import generate_frames, sample_site

        rows = (path / "dets.csv").read_text().split()
        return generate_frames(sample_site(0, "roadside"), len(rows), seed=1, render_images=False)


    register_source("csvdets", _detect, _open, description="CSV detections (plugin)", priority=10)
''')

COMMAND = textwrap.dedent('''
    import typer


    def register(app: typer.Typer) -> None:
        @app.command("hello", help="Say hello.\\n\\nExample: xcalib hello --name site")
        def hello(name: str = typer.Option("world", "--name")) -> None:
            typer.echo(f"hello {name}")
''')


def _package(root: Path, name: str, modules: dict[str, str], entry_points: str) -> Path:
    """A distribution as pip installs one: modules + ``<name>-0.1.dist-info`` with its entry points."""
    root.mkdir(parents=True, exist_ok=True)
    for mod, text in modules.items():
        (root / f"{mod}.py").write_text(text)
    info = root / f"{name}-0.1.dist-info"
    info.mkdir()
    (info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {name}\nVersion: 0.1\n")
    (info / "entry_points.txt").write_text(textwrap.dedent(entry_points))
    return root


def _run(root: Path, code: str) -> subprocess.CompletedProcess:
    import os

    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(root), *sys.path]))
    return subprocess.run([sys.executable, "-c", textwrap.dedent(code)], env=env, capture_output=True, text=True,
                          timeout=300)


def test_xcalib_declares_its_own_extensions():
    names = {e.name for e in entries("xcalib.commands")}
    assert {"calibrate", "bag", "version"} <= names
    assert {e.name for e in entries("xcalib.sources")} >= {"frames", "bags", "formats"}
    with pytest.raises(ValueError, match="xcalib.sources"):
        entries("xcalib.nope")
    assert "xcalib.cost_terms" in GROUPS


def test_a_third_party_source_and_command_need_no_edit_to_xcalib(tmp_path):
    root = _package(tmp_path / "site", "xcalib_demo_plugin", {"csvdets_src": SOURCE, "hello_cmd": COMMAND}, """
        [xcalib.sources]
        csvdets = csvdets_src

        [xcalib.commands]
        hello = hello_cmd
    """)
    data = tmp_path / "recording"
    data.mkdir()
    (data / "dets.csv").write_text("a\nb\nc\n")
    run = _run(root, f"""
        from xcalib.io.sources import find_source, open_source
        from xcalib.cli import main
        print("source", find_source({str(data)!r}).name, len(open_source({str(data)!r})))
        raise SystemExit(main(["hello", "--name", "plugin"]))
    """)
    assert run.returncode == 0, run.stderr
    assert "source csvdets 3" in run.stdout and "hello plugin" in run.stdout
    helptext = _run(root, "from xcalib.cli import main; raise SystemExit(main(['--help']))")
    assert "hello" in helptext.stdout and "calibrate" in helptext.stdout


def test_a_broken_plugin_is_reported_by_name_and_the_rest_still_loads(tmp_path):
    root = _package(tmp_path / "site", "broken_plugin", {"nohook_cmd": "X = 1\n"}, """
        [xcalib.commands]
        ghost = no_such_module_anywhere
        nohook = nohook_cmd

        [xcalib.sources]
        ghostsrc = no_such_source_module
    """)
    run = _run(root, """
        import warnings
        warnings.simplefilter("always")
        from xcalib.cli import COMMANDS
        from xcalib.io.sources import frame_sources
        from xcalib.plugins import plugin_errors
        print("commands", sorted(COMMANDS))
        print("sources", sorted(s.name for s in frame_sources()))
        print("errors", sorted(plugin_errors()))
    """)
    assert run.returncode == 0, run.stderr
    assert "'ghost'" in run.stderr and "no_such_module_anywhere" in run.stderr and "broken_plugin" in run.stderr
    assert "'nohook'" in run.stderr and "register(app)" in run.stderr
    assert "'ghostsrc'" in run.stderr
    assert "'calibrate'" in run.stdout and "'bag'" in run.stdout  # the built-ins still load
    assert "xcalib.commands:ghost" in run.stdout and "xcalib.sources:ghostsrc" in run.stdout
