"""The import graph of our packages, read from their source with ast (nothing is imported).

A node is a module (``pfdoa.gateway.setup``; a package is its ``__init__``). An edge
``a -> b`` is an import statement in ``a`` that names ``b``: ``import b``, ``from b import
x`` (an edge to ``b.x`` instead when ``b.x`` is a module of ours), relative imports
resolved. Every import statement counts wherever it is: at module level, inside a
function (a lazy import still makes the importer depend on the imported module at run
time), under ``if TYPE_CHECKING``, in a ``try``. Importing ``a.b`` also runs ``a``'s
``__init__``; that implicit edge is not drawn (a package importing its own submodules is
the ordinary layout, not a cycle).
"""

from __future__ import annotations

import ast
from dataclasses import dataclass, field
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
ROOTS = {"pfdoa": REPO / "host" / "pfdoa", "pfdoasim": REPO / "sim" / "pfdoasim"}


@dataclass
class Graph:
    files: dict[str, Path] = field(default_factory=dict)  # module -> source file
    edges: dict[str, dict[str, int]] = field(default_factory=dict)  # module -> {imported: first line}

    def ours(self, name: str) -> bool:
        return name in self.files


def module_name(root_pkg: str, root: Path, path: Path) -> str:
    parts = [root_pkg, *path.relative_to(root).with_suffix("").parts]
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _imports(tree: ast.AST, module: str, is_pkg: bool) -> list[tuple[str, list[str], int]]:
    """(base module, names imported from it or [], line) for every import statement."""
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out += [(a.name, [], node.lineno) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                pkg = module.split(".") if is_pkg else module.split(".")[:-1]
                pkg = pkg[: len(pkg) - (node.level - 1)]
                base = ".".join(pkg + ([base] if base else []))
            out.append((base, [a.name for a in node.names], node.lineno))
    return out


def build(roots: dict[str, Path] = ROOTS) -> Graph:
    g = Graph()
    trees = {}
    for pkg, root in roots.items():
        for path in sorted(root.rglob("*.py")):
            name = module_name(pkg, root, path)
            g.files[name] = path
            trees[name] = ast.parse(path.read_text(encoding="utf-8"), str(path))
    for name, tree in trees.items():
        edges: dict[str, int] = {}
        for base, names, line in _imports(tree, name, g.files[name].name == "__init__.py"):
            targets = [f"{base}.{n}" for n in names if f"{base}.{n}" in g.files]
            if not targets or len(targets) < len(names):
                targets.append(base)  # names that are not modules come from base itself
            for t in targets:
                if t != name:
                    edges.setdefault(t, line)
        g.edges[name] = edges
    return g


def cycles(g: Graph) -> list[list[str]]:
    """The strongly connected components with more than one module (Tarjan), each sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    out: list[list[str]] = []
    counter = [0]

    def visit(v: str) -> None:
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in g.edges.get(v, {}):
            if not g.ours(w):
                continue
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(g.files):
        if v not in index:
            visit(v)
    return sorted(out)
