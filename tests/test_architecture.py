"""The package layout: data flows one way through the stages (README, "Layout").

Every import inside doodlecam -- module level or inside a function, so lazy
imports count too -- must point down this stack, or stay inside its own
subpackage; and no group of modules may import each other in a circle.
"""

from __future__ import annotations

import ast
import graphlib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SOURCES = {"doodlecam": ROOT / "doodlecam", "doodlecam.plugins": ROOT / "plugins",
           "doodlecam.postprocessors": ROOT / "postprocessors"}

# Lowest first. A module may import modules of a lower rank, or of its own
# subpackage (doodlecam.plan.x -> doodlecam.plan.y); nothing else.
LAYERS: list[tuple[str, ...]] = [
    ("doodlecam.geometry.kernels",),  # compiled B-spline kernels: NumPy and numba only
    ("doodlecam.errors",),
    ("doodlecam.atomic", "doodlecam.collector", "doodlecam.extras", "doodlecam.memory", "doodlecam.options",
     "doodlecam.plausible"),
    ("doodlecam.model", "doodlecam.schema"),  # schema: the machine profile's pydantic models
    ("doodlecam.api", "doodlecam.machine"),
    ("doodlecam.registry",),  # the ground ends here
    ("doodlecam.geometry", "doodlecam.motion", "doodlecam.link"),
    ("doodlecam.trace",),
    ("doodlecam.plan",),
    ("doodlecam.checks",),  # every mistake found before any work
    ("doodlecam.pipeline", "doodlecam.plugins", "doodlecam.postprocessors"),
    ("doodlecam.plot", "doodlecam.batch", "doodlecam.calibration", "doodlecam.studio"),
    ("doodlecam.cli",),
    ("doodlecam.__main__",),
]
RANK = {prefix: i for i, group in enumerate(LAYERS) for prefix in group}


def module_files() -> dict[str, Path]:
    out = {}
    for package, folder in SOURCES.items():
        for path in folder.rglob("*.py"):
            parts = path.relative_to(folder).with_suffix("").parts
            name = ".".join((package, *parts))
            out[name.removesuffix(".__init__")] = path
    return out


MODULES = module_files()


def layer(module: str) -> tuple[str, int]:
    """(the layer entry a module belongs to, its rank): the longest matching prefix."""
    if module == "doodlecam":
        return module, 0  # the package itself: __version__ only
    best = max((p for p in RANK if module == p or module.startswith(p + ".")), key=len, default=None)
    assert best is not None, f"{module} is in no layer of tests/test_architecture.py; add it"
    return best, RANK[best]


def _type_checking(node: ast.If) -> bool:
    t = node.test
    return (isinstance(t, ast.Name) and t.id == "TYPE_CHECKING") or (
        isinstance(t, ast.Attribute) and t.attr == "TYPE_CHECKING")


def imports_of(module: str, path: Path) -> set[str]:
    """The doodlecam modules ``module`` imports (annotations-only imports excluded)."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    skip = {id(n) for node in ast.walk(tree) if isinstance(node, ast.If) and _type_checking(node)
            for n in ast.walk(node)}
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    found = set()
    for node in ast.walk(tree):
        if id(node) in skip:
            continue
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parts = package.split(".")
                base = ".".join(parts[:len(parts) - node.level + 1] + ([base] if base else []))
            # `from pkg import mod` imports the module pkg.mod; `from mod import name` the module
            names = [f"{base}.{a.name}" if f"{base}.{a.name}" in MODULES else base for a in node.names]
        else:
            continue
        found.update(n for n in names if n in MODULES and n != module)
    return found


GRAPH = {m: imports_of(m, p) for m, p in MODULES.items()}


def _package(module: str) -> str:
    return layer(module)[0]


@pytest.mark.parametrize("module", sorted(MODULES))
def test_imports_point_down_the_pipeline(module):
    mine, rank = layer(module)
    wrong = []
    for target in sorted(GRAPH[module]):
        theirs, their_rank = layer(target)
        if theirs == mine or target == mine or module.startswith(target + "."):
            continue  # inside one subpackage, or the subpackage's own __init__
        if their_rank >= rank:
            wrong.append(f"{target} (layer {theirs!r})")
    assert not wrong, f"{module} (layer {mine!r}) imports upward or sideways: {', '.join(wrong)}"


def test_no_import_cycles():
    sorter = graphlib.TopologicalSorter({m: {t for t in ts if not m.startswith(t + ".")} for m, ts in GRAPH.items()})
    try:
        sorter.prepare()
    except graphlib.CycleError as e:
        pytest.fail(f"import cycle: {' -> '.join(e.args[1])}")


def test_the_check_catches_an_upward_import(tmp_path):
    """The checker itself: a lazy import of the planner from the model is found."""
    fake = tmp_path / "model.py"
    fake.write_text("def f():\n    from doodlecam.plan.planner import plan_stroke\n")
    assert "doodlecam.plan.planner" in imports_of("doodlecam.model", fake)
    assert layer("doodlecam.plan.planner")[1] > layer("doodlecam.model")[1]


def test_the_core_reaches_plugins_only_through_the_registry():
    for module, targets in GRAPH.items():
        if _package(module) in ("doodlecam.plugins", "doodlecam.postprocessors"):
            continue
        assert not {t for t in targets if _package(t) in ("doodlecam.plugins", "doodlecam.postprocessors")}, module
