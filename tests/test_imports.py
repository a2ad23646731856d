"""The package imports in one direction: no import circle among the modules of ``msam_torch``,
function-level imports included (hidden circles such as ``api <-> simulation_mode`` and
``diagnose.core <-> diagnose.simulated`` once were); imports for type checkers only do not run and
do not count."""
import ast
from graphlib import CycleError, TopologicalSorter
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PACKAGE = ROOT / "msam_torch"


def module_name(path: Path) -> str:
    parts = path.relative_to(ROOT).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


MODULES = {module_name(p): p for p in PACKAGE.rglob("*.py")}


def imports(name: str, path: Path) -> set[str]:
    """Modules of the package that ``path`` imports anywhere in its body at run time."""
    package = name if path.stem == "__init__" else name.rpartition(".")[0]
    tree = ast.parse(path.read_text())
    typing_only = {id(n) for block in ast.walk(tree) if isinstance(block, ast.If)
                   and ast.unparse(block.test) in ("TYPE_CHECKING", "typing.TYPE_CHECKING")
                   for stmt in block.body for n in ast.walk(stmt)}
    found = set()
    for node in (n for n in ast.walk(tree) if id(n) not in typing_only):
        if isinstance(node, ast.ImportFrom):
            base = package
            for _ in range(node.level - 1):
                base = base.rpartition(".")[0]
            target = (f"{base}.{node.module}" if node.module else base) if node.level else node.module or ""
            for alias in node.names:  # ``from .x import y``: the module x.y if there is one, else x
                found.add(f"{target}.{alias.name}" if f"{target}.{alias.name}" in MODULES else target)
        elif isinstance(node, ast.Import):
            found |= {a.name for a in node.names}
    found = {m for m in found if m in MODULES}
    # importing a.b.c runs the package a.b's __init__ first, unless the importer lives in a.b
    parents = {".".join(m.split(".")[:k]) for m in found for k in range(2, m.count(".") + 1)}
    return (found | {p for p in parents if p in MODULES and not name.startswith(p + ".")}) - {name}


GRAPH = {name: imports(name, path) for name, path in MODULES.items()}


def test_no_import_circle_in_the_package():
    try:
        order = list(TopologicalSorter(GRAPH).static_order())
    except CycleError as error:
        pytest.fail(f"import circle: {' -> '.join(error.args[1])}")
    assert order.index("msam_torch.simulation.solver") < order.index("msam_torch.run.adapt")
    assert order.index("msam_torch.diagnose.stages.simulated") < order.index("msam_torch.diagnose.stages.pipeline")


def test_the_checker_sees_a_function_level_circle(tmp_path):
    """A circle closed by an import inside a function is found (the check can fail)."""
    graph = dict(GRAPH)
    graph["msam_torch.run.plan"] = graph["msam_torch.run.plan"] | {"msam_torch.run.adapt"}  # api imports plan
    with pytest.raises(CycleError):
        list(TopologicalSorter(graph).static_order())
    source = "def f():\n    from .run.adapt import adapt\n    from .simulation.ode import SystemModel\n"
    (tmp_path / "m.py").write_text(source)
    assert {"msam_torch.run.adapt", "msam_torch.simulation.ode", "msam_torch.simulation"} <= imports("msam_torch.m", tmp_path / "m.py")
