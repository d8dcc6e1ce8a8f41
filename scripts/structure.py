"""Structural counts of ``src/xcalib`` (issue 28), from the source text alone (``ast``, nothing imported).

* ``wide``: functions with more than 8 parameters (``self`` / ``cls`` not counted, ``*args`` /
  ``**kwargs`` not counted), except CLI callbacks (functions decorated ``@app.command`` /
  ``@app.callback`` in ``xcalib.cli``).
* ``private``: imports of a private name across packages: an import in package A (``xcalib.calib``,
  ``xcalib.io``, ...; a top-level module is its own package) of a module or name of package B != A
  (a module directly in ``xcalib/`` belongs to ``xcalib``)
  whose dotted path or imported name has a component starting with one underscore
  (``xcalib.io._files``, ``from ..calib.cost import _pair_features``). Each import counts once.
* ``cycles``: import cycles between modules (strongly connected components of more than one module
  in the graph of every import, at module level or inside a function, except those under
  ``if TYPE_CHECKING:`` (annotations only); an import of a package counts as an import of its
  ``__init__``, ``from pkg import mod`` as one of ``pkg.mod``).
* ``meta``: reads of a ``meta`` key in a package other than the one(s) that write it (``Frame.meta``,
  ``CalibrationResult.meta``: a key one package sets and another reads is an untyped interface; give
  the record a typed field instead). A read is ``<x>meta["k"]``, ``<x>meta.get("k")``, ``"k" in
  <x>meta`` (also through ``(<x>.meta or {})`` / ``getattr(<x>, "meta", ...) or {}``), where ``<x>meta``
  is a name ending in ``meta`` or an attribute ``.meta``; a write is ``<x>meta["k"] = ...``,
  ``<x>meta.setdefault("k", ...)``, or a dict literal key assigned to such a name or passed as
  ``meta=``. A read counts when the key is written somewhere in ``src/xcalib`` but not in the
  reading package (keys written nowhere, e.g. a file's own fields, are not counted). Each read
  counts once per (module, key).

Usage: ``python scripts/structure.py [--list]`` prints the counts (``--list``: every item).
``tests/test_structure.py`` holds them to a ratchet.
"""

from __future__ import annotations

import argparse
import ast
import json
from dataclasses import dataclass, field
from pathlib import Path

MAX_PARAMS = 8
SRC = Path(__file__).resolve().parents[1] / "src"


@dataclass
class Counts:
    wide: list[str] = field(default_factory=list)      # "module:function (n)"
    private: list[str] = field(default_factory=list)   # "importer -> target"
    cycles: list[list[str]] = field(default_factory=list)
    meta: list[str] = field(default_factory=list)      # "reader module reads 'key' (written in: ...)"

    def summary(self) -> dict[str, int]:
        return {"wide": len(self.wide), "private": len(self.private), "cycles": len(self.cycles),
                "meta": len(self.meta)}


def _modules(src: Path) -> dict[str, Path]:
    out = {}
    for p in sorted((src / "xcalib").rglob("*.py")):
        parts = list(p.relative_to(src).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        out[".".join(parts)] = p
    return out


def _package(mod: str, packages: set[str]) -> str:
    """The first-level package of ``mod``: ``xcalib.calib.api`` -> ``xcalib.calib``; a module directly
    in ``xcalib/`` (``xcalib.errors``, ``xcalib._version``) -> ``xcalib``."""
    top = ".".join(mod.split(".")[:2])
    return top if top in packages else "xcalib"


def _is_private(dotted: str) -> bool:
    return any(c.startswith("_") and not c.startswith("__") for c in dotted.split("."))


def _n_params(fn: ast.FunctionDef | ast.AsyncFunctionDef, method: bool) -> int:
    a = fn.args
    names = [x.arg for x in [*a.posonlyargs, *a.args, *a.kwonlyargs]]
    if method and names and names[0] in ("self", "cls"):
        names = names[1:]
    return len(names)


def _is_cli_callback(fn) -> bool:
    for d in fn.decorator_list:
        f = d.func if isinstance(d, ast.Call) else d
        if isinstance(f, ast.Attribute) and f.attr in ("command", "callback"):
            return True
    return False


def _resolve(mod: str, is_pkg: bool, node: ast.ImportFrom) -> str:
    if not node.level:
        return node.module or ""
    base = mod.split(".") if is_pkg else mod.split(".")[:-1]
    base = base[: len(base) - (node.level - 1)]
    return ".".join(base + ([node.module] if node.module else []))


def count(src: Path = SRC) -> Counts:
    mods = _modules(src)
    packages = {m for m, p in mods.items() if p.name == "__init__.py"}
    out = Counts()
    graph: dict[str, set[str]] = {m: set() for m in mods}
    for mod, path in mods.items():
        tree = ast.parse(path.read_text(), str(path))
        is_pkg = path.name == "__init__.py"
        cli = mod.startswith("xcalib.cli")

        def visit(node, in_class: bool) -> None:
            for child in ast.iter_child_nodes(node):
                if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef)):
                    n = _n_params(child, in_class)
                    if n > MAX_PARAMS and not (cli and _is_cli_callback(child)):
                        out.wide.append(f"{mod}:{child.name} ({n})")
                    visit(child, False)
                elif isinstance(child, ast.ClassDef):
                    visit(child, True)
                else:
                    visit(child, in_class)

        visit(tree, False)
        typing_only = {id(n) for t in ast.walk(tree) if isinstance(t, ast.If) and _is_type_checking(t.test)
                       for stmt in t.body for n in ast.walk(stmt)}
        for node in ast.walk(tree):
            targets: list[tuple[str, str]] = []  # (module imported, name or "")
            if isinstance(node, ast.Import):
                targets = [(a.name, "") for a in node.names if a.name.startswith("xcalib")]
            elif isinstance(node, ast.ImportFrom):
                base = _resolve(mod, is_pkg, node)
                if base.startswith("xcalib"):
                    targets = [(base, a.name) for a in node.names]
            for base, name in targets:
                sub = f"{base}.{name}" if name else base
                target = sub if sub in mods else base
                if target in mods and target != mod and id(node) not in typing_only:
                    graph[mod].add(target)
                if _package(base, packages) != _package(mod, packages) and (_is_private(base) or _is_private(name)):
                    out.private.append(f"{mod} -> {sub}")
    out.cycles = _cycles(graph)
    out.meta = _cross_meta(mods, packages)
    return out


def _is_meta(node: ast.expr) -> bool:
    """``<x>meta`` / ``<x>.meta``, also as ``(<x>.meta or {})`` and ``getattr(<x>, "meta", ...)``."""
    if isinstance(node, ast.BoolOp) and isinstance(node.op, ast.Or):
        return _is_meta(node.values[0])
    if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id == "getattr":
        return len(node.args) >= 2 and isinstance(node.args[1], ast.Constant) and node.args[1].value == "meta"
    return (isinstance(node, ast.Name) and node.id.endswith("meta")) or \
        (isinstance(node, ast.Attribute) and node.attr == "meta")


def _key(node) -> str | None:
    return node.value if isinstance(node, ast.Constant) and isinstance(node.value, str) else None


def _meta_uses(tree: ast.AST) -> tuple[set[str], list[str]]:
    """(keys written, keys read) of ``meta`` dicts in one module (see the module docstring)."""
    writes, reads = set(), []
    for n in ast.walk(tree):
        if isinstance(n, ast.Subscript) and _is_meta(n.value) and _key(n.slice) is not None:
            (writes.add if isinstance(n.ctx, ast.Store) else reads.append)(_key(n.slice))
        elif isinstance(n, ast.Call) and isinstance(n.func, ast.Attribute) and _is_meta(n.func.value) and n.args \
                and _key(n.args[0]) is not None and n.func.attr in ("get", "setdefault", "pop"):
            (writes.add if n.func.attr == "setdefault" else reads.append)(_key(n.args[0]))
        elif isinstance(n, ast.Compare) and len(n.ops) == 1 and isinstance(n.ops[0], (ast.In, ast.NotIn)) \
                and _is_meta(n.comparators[0]) and _key(n.left) is not None:
            reads.append(_key(n.left))
        elif isinstance(n, ast.keyword) and n.arg == "meta" and isinstance(n.value, ast.Dict):
            writes.update(k for k in map(_key, n.value.keys) if k is not None)
        elif isinstance(n, (ast.Assign, ast.AnnAssign)) and isinstance(n.value, ast.Dict) and \
                any(_is_meta(t) for t in (n.targets if isinstance(n, ast.Assign) else [n.target])):
            writes.update(k for k in map(_key, n.value.keys) if k is not None)
    return writes, reads


def _cross_meta(mods: dict[str, Path], packages: set[str]) -> list[str]:
    written: dict[str, set[str]] = {}
    read: dict[tuple[str, str], str] = {}
    for mod, path in mods.items():
        pkg = _package(mod, packages)
        w, r = _meta_uses(ast.parse(path.read_text(), str(path)))
        for k in w:
            written.setdefault(k, set()).add(pkg)
        for k in r:
            read.setdefault((mod, k), pkg)
    return sorted(f"{mod} reads {k!r} (written in: {', '.join(sorted(written[k]))})"
                  for (mod, k), pkg in read.items() if k in written and pkg not in written[k])


def _is_type_checking(test: ast.expr) -> bool:
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or \
        (isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING")


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan, iterative)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    on, stack, comps, counter = set(), [], [], [0]
    for root in sorted(graph):
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = counter[0]
        counter[0] += 1
        stack.append(root)
        on.add(root)
        while work:
            v, it = work[-1]
            for w in it:
                if w not in index:
                    index[w] = low[w] = counter[0]
                    counter[0] += 1
                    stack.append(w)
                    on.add(w)
                    work.append((w, iter(sorted(graph.get(w, ())))))
                    break
                if w in on:
                    low[v] = min(low[v], index[w])
            else:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[v])
                if low[v] == index[v]:
                    comp = []
                    while True:
                        w = stack.pop()
                        on.discard(w)
                        comp.append(w)
                        if w == v:
                            break
                    if len(comp) > 1:
                        comps.append(sorted(comp))
    return sorted(comps)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--list", action="store_true", help="print every item")
    args = ap.parse_args()
    c = count()
    print(json.dumps(c.summary()))
    if args.list:
        for title, items in (("wide", c.wide), ("private", c.private), ("cycles", c.cycles), ("meta", c.meta)):
            print(f"\n{title}:")
            for item in items:
                print(f"  {item}")


if __name__ == "__main__":
    main()
