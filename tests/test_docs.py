"""Every code block in README.md and docs/*.md runs as written.

Rules (checked here):
* ```python fences are executed, per document in order, in one namespace, in a temporary folder
  (```python norun: a module of a plug-in package, shown and not run);
* ```bash / ```console fences are executed when every command starts with ``xcalib`` (console:
  lines starting with ``$ ``; others are output) — through the CLI entry point, in the same
  folder, each must exit 0;
* every other fence must say explicitly that it does not run: a non-shell language such as
  ```text / ```json / ```yaml, or ``norun`` after the language (```bash norun).
"""

from __future__ import annotations

import os
import re
import shlex
from dataclasses import dataclass
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
DOCS = sorted((REPO / "docs").glob("*.md")) + [REPO / "README.md"]
SHELL = {"bash", "sh", "shell", "console"}
QUIET = {"text", "json", "yaml", "toml", "ini", "html", "csv", "diff", "pcd"}
_FENCE = re.compile(r"^(?P<indent> {0,3})(?P<tick>`{3,}|~{3,})(?P<info>[^\n`]*)$")


@dataclass
class Block:
    path: Path
    line: int
    lang: str
    flags: tuple[str, ...]
    code: str


def code_blocks(path: Path) -> list[Block]:
    """Fenced code blocks of a Markdown file, in order (line = 1-based line of the opening fence)."""
    out: list[Block] = []
    lines = path.read_text(encoding="utf-8").splitlines()
    i = 0
    while i < len(lines):
        m = _FENCE.match(lines[i])
        if not m:
            i += 1
            continue
        tick, info = m["tick"], m["info"].strip().split()
        body, j = [], i + 1
        while j < len(lines) and not lines[j].strip().startswith(tick):
            body.append(lines[j][len(m["indent"]):] if lines[j].startswith(m["indent"]) else lines[j])
            j += 1
        lang = info[0].lower() if info else ""
        out.append(Block(path, i + 1, lang, tuple(w.lower() for w in info[1:]), "\n".join(body) + "\n"))
        i = j + 1
    return out


def shell_commands(block: Block) -> list[str]:
    """Commands of a shell fence (continuation lines joined; console: only ``$ `` lines)."""
    raw = block.code.splitlines()
    if block.lang == "console":
        raw = [ln[2:] for ln in raw if ln.startswith("$ ")]
    cmds, cur = [], ""
    for ln in raw:
        s = ln.strip()
        if not s or (s.startswith("#") and not cur):
            continue
        if s.endswith("\\"):
            cur += s[:-1] + " "
            continue
        cmds.append((cur + s).strip())
        cur = ""
    if cur.strip():
        cmds.append(cur.strip())
    return cmds


_NEEDS_WEIGHTS = re.compile(r'site="synthetic"|xcalib (match|validate|export|demo)\b')


def shipped_weights_present() -> bool:
    from xcalib.engine.checkpoint import packaged_weights_dir

    return (packaged_weights_dir() / "synthetic" / "fastmatch.pt").is_file()


def runnable(block: Block) -> bool:
    return (block.lang == "python" or block.lang in SHELL) and "norun" not in block.flags


@pytest.mark.parametrize("path", DOCS, ids=lambda p: p.relative_to(REPO).as_posix())
def test_every_fence_is_tagged(path):
    for b in code_blocks(path):
        where = f"{path.name}:{b.line}"
        assert b.lang, f"{where}: untagged fence; say ```python, ```bash (xcalib commands) or ```text"
        if b.lang in SHELL and "norun" not in b.flags:
            for cmd in shell_commands(b):
                assert cmd.split()[0] == "xcalib", \
                    f"{where}: shell fence runs `{cmd}`; only xcalib commands run here (mark it ```{b.lang} norun)"
        elif b.lang != "python":
            assert b.lang in QUIET or "norun" in b.flags, f"{where}: unknown fence language {b.lang!r}"


def test_docs_index_links_every_page():
    index = (REPO / "docs" / "index.md").read_text()
    for p in DOCS:
        if p.parent.name == "docs" and p.name != "index.md":
            assert f"({p.name})" in index, f"docs/index.md does not link {p.name}"
    for target in re.findall(r"\]\(([^)#:]+\.md)", index):
        assert (REPO / "docs" / target).is_file(), f"docs/index.md links a missing page {target}"


@pytest.mark.parametrize("path", DOCS, ids=lambda p: p.relative_to(REPO).as_posix())
def test_code_blocks_run(path, tmp_path, monkeypatch, capsys):
    from xcalib.cli import main

    blocks = [b for b in code_blocks(path) if runnable(b)]
    if not blocks:
        pytest.skip(f"{path.name} has no runnable blocks")
    if not shipped_weights_present() and any(_NEEDS_WEIGHTS.search(b.code) for b in blocks):
        pytest.skip(f"{path.name} uses the shipped fastmatch weights (site 'synthetic'), not in the package yet")
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("XCALIB_HOME", str(tmp_path / "xcalib-home"))
    monkeypatch.setenv("OMP_NUM_THREADS", "1")
    ns: dict = {"__name__": "__docs__"}
    for b in blocks:
        where = f"{path.relative_to(REPO)}:{b.line}"
        if b.lang == "python":
            try:
                exec(compile(b.code, where, "exec"), ns)  # noqa: S102 - the docs are ours
            except Exception as exc:  # noqa: BLE001
                pytest.fail(f"{where}: python block failed: {type(exc).__name__}: {exc}")
        else:
            for cmd in shell_commands(b):
                argv = shlex.split(cmd, comments=True)
                rc = main(argv[1:])
                captured = capsys.readouterr()
                assert rc == 0, f"{where}: `{cmd}` exited {rc}\n{captured.out[-2000:]}\n{captured.err[-2000:]}"
    assert os.getcwd() == str(tmp_path)
