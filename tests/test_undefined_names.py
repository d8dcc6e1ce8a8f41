"""Every name a function in ``src/``, ``benchmarks/`` or ``scripts/`` reads as a global is defined in
its module or is a builtin: a cheap static check that catches a misspelt call in code the suite does
not run (``bench_deploy.py`` once called an ``evaluatematcher_for`` that never existed)."""

from __future__ import annotations

import builtins
import symtable
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
FILES = sorted([*(ROOT / "src").rglob("*.py"), *(ROOT / "benchmarks").glob("*.py"), *(ROOT / "scripts").glob("*.py")])


def undefined_globals(source: str, filename: str) -> list[str]:
    """``name (line of its scope)`` for each global read inside a function or class body that the
    module never binds (assignment, import, def, class, ``global`` statement) and that is no builtin."""
    top = symtable.symtable(source, filename, "exec")
    bound = {s.get_name() for s in top.get_symbols() if s.is_assigned() or s.is_imported() or s.is_namespace()}
    if "*" in bound or any(s.get_name() == "*" for s in top.get_symbols()):
        return []  # a star import binds names we cannot see

    def walk(table) -> list[str]:
        bound.update(s.get_name() for s in table.get_symbols() if s.is_declared_global() and s.is_assigned())
        out = []
        for s in table.get_symbols():
            if ((s.is_global() and not s.is_declared_global()) and s.is_referenced()
                    and s.get_name() not in bound and not hasattr(builtins, s.get_name())
                    and s.get_name() not in ("__file__", "__name__", "__doc__", "__spec__", "__builtins__",
                                             "__class__", "__module__", "__qualname__", "__annotations__")):
                out.append(f"{s.get_name()} (in {table.get_name()}, line {table.get_lineno()})")
        for child in table.get_children():
            out.extend(walk(child))
        return out

    return [x for child in top.get_children() for x in walk(child)]


def test_the_check_finds_a_misspelt_call():
    src = "import os\n\ndef f():\n    return os.sep + helpr()\n\ndef helper():\n    return ''\n"
    assert undefined_globals(src, "x.py") == ["helpr (in f, line 3)"]
    assert undefined_globals(src.replace("helpr", "helper"), "x.py") == []


@pytest.mark.parametrize("path", FILES, ids=lambda p: str(p.relative_to(ROOT)))
def test_no_undefined_global(path):
    bad = undefined_globals(path.read_text(encoding="utf-8"), str(path))
    assert not bad, f"{path.relative_to(ROOT)} reads names that are never defined: {bad}"
