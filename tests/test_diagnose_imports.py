"""The diagnosis stages import each other in one direction: no import circle among the modules of
``msam_torch.diagnose``, function-level imports included."""
import ast
from graphlib import TopologicalSorter
from pathlib import Path

PACKAGE = Path(__file__).resolve().parent.parent / "msam_torch" / "diagnose"


def imports(path: Path) -> set[str]:
    """Modules of the package that ``path`` imports anywhere in its body (``from .x import y``,
    ``from . import x``)."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.level == 1:
            found |= {node.module.split(".")[0]} if node.module else {a.name for a in node.names}
    return found


def test_no_import_circle_among_the_diagnosis_stages():
    graph = {path.stem: {m for m in imports(path) if (PACKAGE / f"{m}.py").exists()}
             for path in PACKAGE.glob("*.py") if path.stem != "__init__"}
    order = list(TopologicalSorter(graph).static_order())  # raises CycleError on a circle
    assert {"core", "simulated", "equation", "verdict", "weak"} <= set(order)
    assert order.index("simulated") < order.index("core") and "core" not in graph["simulated"]
    assert graph["core"] >= {"equation", "compare", "simulated", "verdict"}
