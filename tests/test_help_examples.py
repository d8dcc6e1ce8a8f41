"""The examples in every command's --help, as a new user copies them.

* every ``Example: xcalib ...`` line of every command and sub-command parses: its options exist
  and its values have the right types (a renamed option or a wrong value fails here);
* the examples that need only the docs' synthetic session (``site/test.h5``, ``site.mcap``, see
  docs/cli.md) and the shared real data run as written and exit 0 (a frame key or camera name
  that the session does not have fails here).
"""

from __future__ import annotations

import re
import shlex

import pytest
import typer.main

from conftest import SHARED_DATA
from xcalib.cli import app, main

_LINE = re.compile(r"^(?:Example[^:]*:\s*)?xcalib ([a-z].*)$")


def _walk(cmd, path):
    yield path, cmd
    for name, sub in getattr(cmd, "commands", {}).items():
        yield from _walk(sub, path + [name])


def _argv(text: str) -> list[str]:
    """An example line as argv: a trailing ``  (note)`` and a shell redirection are not arguments."""
    text = re.split(r"\s{2,}\(|\s+>\s", text)[0]
    return shlex.split(text)


def help_examples() -> list[tuple[str, list[str]]]:
    """(the command whose --help shows it, argv) of every example line, deduplicated."""
    root = typer.main.get_command(app)
    seen, out = set(), []
    for path, cmd in _walk(root, []):
        for line in (cmd.help or "").splitlines():
            m = _LINE.match(line.strip())
            if m and m.group(1) not in seen:
                seen.add(m.group(1))
                out.append((" ".join(path) or "xcalib", _argv(m.group(1))))
    return out


EXAMPLES = help_examples()


def test_examples_are_found_for_every_command():
    shown = {argv[0] for _, argv in EXAMPLES}
    root = typer.main.get_command(app)
    assert set(root.commands) <= shown, f"commands whose --help shows no example: {set(root.commands) - shown}"
    assert any(_LINE.match(ln.strip()) for ln in root.help.splitlines()), "`xcalib --help` shows no example"


@pytest.mark.parametrize("where,argv", EXAMPLES, ids=[" ".join(a[:2]) for _, a in EXAMPLES])
def test_every_help_example_parses(where, argv):
    cmd = typer.main.get_command(app)
    args = list(argv)
    name = "xcalib"
    while hasattr(cmd, "commands") and args and args[0] in cmd.commands:
        name, cmd = args[0], cmd.commands[args.pop(0)]
    assert not hasattr(cmd, "commands"), f"xcalib {where} --help: example {argv} names no command"
    ctx = cmd.make_context(name, args)  # raises click's UsageError/BadParameter on a wrong option or value
    assert ctx.params is not None


def test_synthetic_session_examples_run_as_written(tmp_path, monkeypatch):
    """After the docs' first commands (docs/cli.md: synth, bag write), the --help examples on
    ``site/test.h5`` and ``site.mcap`` run and exit 0 (``match``, which loads a model, is checked
    for its frame key only: test_docs runs it)."""
    from xcalib.io.hdf5 import CacheReader

    monkeypatch.chdir(tmp_path)
    assert main(["synth", "--out", "site", "--frames", "8", "--train", "0", "--val", "0", "--test", "8", "--seed", "1",
                 "--set", "width=960", "--set", "height=600", "--set", "focal_px=900", "--no-images",
                 "--no-lidar"]) == 0
    assert main(["bag", "write", "site/test.h5", "site.mcap", "--frames", "0:4"]) == 0
    keys = list(CacheReader("site/test.h5").frame_keys)
    ran = []
    for _, argv in EXAMPLES:
        if "site/test.h5" not in argv and "site.mcap" not in argv:
            continue
        if argv[0] == "match" and "--key" in argv:
            assert argv[argv.index("--key") + 1] in keys, f"xcalib {' '.join(argv)}: the docs' site has keys {keys}"
            ran.append(argv[:2])
        elif argv[0] in ("cache", "bag") and argv[1] in ("info", "frames"):
            assert main(argv) == 0, f"xcalib {' '.join(argv)} failed"
            ran.append(argv[:2])
    assert ["match", "site/test.h5"] in ran and ["bag", "frames"] in ran and ["cache", "info"] in ran


def test_convert_example_runs_on_the_shared_data(tmp_path, monkeypatch):
    if not (SHARED_DATA / "calibanything" / "format_examples" / "lucid_calib.json").exists():
        pytest.skip("real data not available")
    (tmp_path / "work").mkdir()
    (tmp_path / "shared").symlink_to(SHARED_DATA.parent)  # `../shared/data` as the examples write it
    monkeypatch.chdir(tmp_path / "work")
    argv = next(a for _, a in EXAMPLES if a[0] == "convert")
    assert main(argv) == 0 and (tmp_path / "work" / "calib.json").exists()


def test_version_flag_prints_what_the_version_command_prints(capsys):
    assert main(["--version"]) == 0
    flag = capsys.readouterr().out
    assert main(["version"]) == 0
    assert flag == capsys.readouterr().out and flag.startswith("xcalib ")


def test_monitor_example_runs_as_written_and_says_ok(tmp_path, monkeypatch, capsys):
    """``xcalib monitor --help`` shows a stream the package makes, its calibration and the monitor on it,
    in that order; copied as written they exit 0 and the monitor says ok (session 15: the example had been
    A9's 16 frames, fewer than one window: exit 1, "could not tell")."""
    monkeypatch.chdir(tmp_path)
    chain = [argv for where, argv in EXAMPLES if where == "monitor" and "stream" in " ".join(argv)]
    assert [a[0] for a in chain] == ["synth", "calibrate", "monitor"], chain
    for argv in chain:
        assert main(argv) == 0, f"xcalib {' '.join(argv)} failed"
    assert "state: ok (exit code 0)" in capsys.readouterr().out
