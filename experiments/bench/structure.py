"""Import structure of the msam_torch package: modules, import links, circles, levels.

Two scales: modules (every file), and rooms (the package's top-level modules and subpackages,
``msam_torch.run`` standing for every module under it). ``levels`` is the rooms' (a room stands
one level above every room it imports; the package's ``__init__`` is a room of its own),
``module_levels`` the same between modules.

Every ``import`` and ``from ... import`` statement anywhere in a module counts (inside functions
and ``if TYPE_CHECKING:`` blocks too), and so does a string constant naming a module of the
package (``"msam_torch.engine.step"`` or ``"msam_torch.engine.step:Name"``), as a registry
would load it. ``from package import name`` links to the submodule ``package.name`` when there is
one, else to the package's ``__init__``. Run: ``python -m experiments.bench.structure [ROOT]`` (JSON on stdout; ROOT defaults to this checkout).
"""
from __future__ import annotations

import ast
import json
import sys
from collections import Counter
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
PACKAGE = "msam_torch"


def modules(root: Path = ROOT) -> dict[str, Path]:
    """Dotted name -> file of every module of the package."""
    out = {}
    for path in sorted((root / PACKAGE).rglob("*.py")):
        parts = list(path.relative_to(root).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        out[".".join(parts)] = path
    return out


def _resolve(name: str, known: dict[str, Path]) -> str | None:
    while name and name not in known:
        name = name.rpartition(".")[0]
    return name or None


def links(known: dict[str, Path]) -> dict[str, set[str]]:
    """Module -> the package's modules it imports."""
    graph: dict[str, set[str]] = {}
    for name, path in known.items():
        package = name if path.name == "__init__.py" else name.rpartition(".")[0]
        targets: set[str] = set()
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                targets.update(a.name for a in node.names)
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:
                    anchor = package.split(".")
                    anchor = anchor[:len(anchor) - node.level + 1]
                    base = ".".join(anchor + ([base] if base else []))
                targets.update(f"{base}.{a.name}" if f"{base}.{a.name}" in known else base for a in node.names)
            elif isinstance(node, ast.Constant) and isinstance(node.value, str):
                text = node.value.partition(":")[0]
                if text.startswith(PACKAGE + ".") and text in known:
                    targets.add(text)
        graph[name] = {t for t in (_resolve(t, known) for t in targets if t.split(".")[0] == PACKAGE)
                       if t and t != name}
    return graph


def circles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components of more than one module (Tarjan)."""
    index, low, stack, on, out = {}, {}, [], set(), []
    sys.setrecursionlimit(10000)

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in graph.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            part = []
            while True:
                w = stack.pop()
                on.discard(w)
                part.append(w)
                if w == v:
                    break
            if len(part) > 1:
                out.append(sorted(part))

    for v in graph:
        if v not in index:
            visit(v)
    return out


def levels(graph: dict[str, set[str]]) -> dict[str, int]:
    """A module stands one level above everything it imports (leaves at 1); the modules of a
    circle stand on one level."""
    component = {v: i for i, part in enumerate(circles(graph)) for v in part}
    key = lambda v: component.get(v, v)
    members: dict = {}
    for v in graph:
        members.setdefault(key(v), []).append(v)
    memo: dict = {}

    def level(c):
        if c not in memo:
            below = {key(w) for v in members[c] for w in graph[v]} - {c}
            memo[c] = 1 + max((level(d) for d in below), default=0)
        return memo[c]

    return {v: level(key(v)) for v in graph}


def rooms(graph: dict[str, set[str]]) -> dict[str, set[str]]:
    """The same links between the package's top-level modules and subpackages (each a room)."""
    room = lambda name: ".".join(name.split(".")[:2])
    out: dict[str, set[str]] = {room(m): set() for m in graph}
    for module, targets in graph.items():
        out[room(module)] |= {room(t) for t in targets} - {room(module)}
    return out


def measures(root: Path = ROOT) -> dict:
    known = modules(root)
    graph = links(known)
    level = levels(graph)
    house = rooms(graph)
    room_level = levels(house)
    top = [n for n in known if n.count(".") == 1]
    names = Counter(p.name for p in known.values() if p.name != "__init__.py")
    lines = {n: len(p.read_text().splitlines()) for n, p in known.items()}
    deepest = max(level, key=level.get)
    chain = [deepest]
    while True:  # down the highest import at each step (a circle's modules share a level: it ends there)
        below = [w for w in graph[chain[-1]] if level[w] < level[chain[-1]]]
        if not below:
            break
        chain.append(max(below, key=level.get))
    return {
        "modules": len(known),
        "links": sum(len(v) for v in graph.values()),
        "top_level_modules": len(top),
        "circles": circles(graph),
        "levels": max(room_level.values()),
        "room_circles": circles(house),
        "room_levels": dict(sorted(room_level.items(), key=lambda kv: -kv[1])),
        "module_levels": level[deepest],
        "deepest_module_chain": chain,
        "same_file_names": sorted(n for n, c in names.items() if c > 1),
        "longest_module": max(lines, key=lines.get),
        "longest_module_lines": max(lines.values()),
        "over_400_lines": sorted(n for n, c in lines.items() if c > 400),
    }


if __name__ == "__main__":
    json.dump(measures(Path(sys.argv[1]) if len(sys.argv) > 1 else ROOT), sys.stdout, indent=1)
    print()
