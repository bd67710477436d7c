"""The house rules, checked from the source: layers import only downward, no import cycle, no module over ~400 lines.

Layers, lowest first (docs/architecture.md, "Layout"): ``core`` < ``stages`` < ``evaluation`` < ``datasets`` <
``orchestration`` < ``tracking`` < ``report`` < ``reproduction`` < ``wings`` < ``experiments`` < ``cli``, where the
wings are the experiment kinds' packages (``gtsweep/experiments/<kind>/``: pairs, localization, optimize), each
below the registry that names them (``gtsweep/experiments/*.py``) and none importing another; a package's
``__main__`` is an entry point (nothing imports it) and may use any layer, and so are the top-level commands of
:data:`ENTRY_POINTS`. The science (core, stages, evaluation, datasets) never imports the orchestration, tracking,
report, experiment or command-line layers. Lazy (function-level) imports count.
"""
from __future__ import annotations

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "gtsweep"
LAYERS = ["core", "stages", "evaluation", "datasets", "orchestration", "tracking", "report", "reproduction", "wings",
          "experiments", "cli"]
#: The experiment kinds' packages (the wings): every folder of gtsweep/experiments/.
WINGS = sorted(p.name for p in (PACKAGE / "experiments").iterdir() if (p / "__init__.py").exists())
SCIENCE = {"core", "stages", "evaluation", "datasets"}
MAX_LINES = 400
#: Top-level modules run as commands (``python -m gtsweep``, ``python -m gtsweep.install learned``).
ENTRY_POINTS = {"gtsweep.__main__", "gtsweep.install"}


def _module_name(path: Path) -> str:
    parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _modules() -> dict[str, Path]:
    return {_module_name(p): p for p in PACKAGE.rglob("*.py")}


def _imports(path: Path, modules) -> set[str]:
    """The gtsweep modules ``path`` imports (``from a import b`` counts ``a.b`` when that is a module)."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        names = []
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names = [node.module] + [f"{node.module}.{alias.name}" for alias in node.names]
        elif isinstance(node, ast.Import):
            names = [alias.name for alias in node.names]
        found |= {name for name in names if name in modules}
    return found


def _layer(module: str) -> str | None:
    parts = module.split(".")
    if len(parts) > 2 and parts[1] == "experiments" and parts[2] in WINGS:
        return "wings"
    return parts[1] if len(parts) > 1 and parts[1] in LAYERS else None


def _wing(module: str) -> str | None:
    parts = module.split(".")
    return parts[2] if _layer(module) == "wings" else None


def test_every_module_sits_in_a_layer():
    modules = _modules()
    loose = [m for m in modules if m.count(".") >= 1 and _layer(m) is None and m not in ENTRY_POINTS]
    assert loose == [], f"modules outside the layer subpackages: {loose}"
    importers = [m for m, p in modules.items() if ENTRY_POINTS & _imports(p, modules)]
    assert importers == [], f"an entry point is imported by {importers}"


def test_layers_import_only_downward():
    modules = _modules()
    upward = []
    for module, path in modules.items():
        own = _layer(module)
        if own is None or module.endswith(".__main__"):  # an entry point: nothing imports it
            continue
        for imported in _imports(path, modules):
            other = _layer(imported)
            if other is not None and LAYERS.index(other) > LAYERS.index(own):
                upward.append(f"{module} -> {imported}")
    assert upward == [], "imports against the layers:\n" + "\n".join(sorted(upward))


def test_the_wings_are_the_three_kinds_and_none_imports_another():
    assert WINGS == ["localization", "optimize", "pairs"]
    modules = _modules()
    crossing = [f"{m} -> {i}" for m, p in modules.items() if _wing(m) is not None
                for i in _imports(p, modules) if _wing(i) not in (None, _wing(m))]
    assert crossing == [], "a wing imports another:\n" + "\n".join(sorted(crossing))


def test_science_never_imports_orchestration_tracking_or_cli():
    modules = _modules()
    bad = [f"{m} -> {i}" for m, p in modules.items() if _layer(m) in SCIENCE
           for i in _imports(p, modules) if _layer(i) not in SCIENCE and _layer(i) is not None]
    assert bad == []


def test_no_import_cycle():
    modules = _modules()
    edges = {m: {i for i in _imports(p, modules) if i != m} for m, p in modules.items()}
    # packages' __init__ re-exports are not cycles of code; leave them out as the shared tool does
    edges = {m: {i for i in e if modules[i].name != "__init__.py"} for m, e in edges.items()
             if modules[m].name != "__init__.py"}
    state: dict[str, int] = {}
    cycles = []

    def visit(node: str, stack: list[str]) -> None:
        state[node] = 1
        for nxt in edges.get(node, ()):
            if state.get(nxt) == 1:
                cycles.append(" -> ".join(stack[stack.index(nxt):] + [nxt]))
            elif nxt not in state:
                visit(nxt, stack + [nxt])
        state[node] = 2

    for module in sorted(edges):
        if module not in state:
            visit(module, [module])
    assert cycles == []


@pytest.mark.parametrize("path", sorted(PACKAGE.rglob("*.py")), ids=lambda p: str(p.relative_to(PACKAGE)))
def test_module_size(path):
    assert len(path.read_text().splitlines()) <= MAX_LINES


def test_no_module_level_run_state():
    """No ``global`` statement anywhere: run information travels in arguments, not module globals."""
    offenders = [str(p.relative_to(PACKAGE)) for p in PACKAGE.rglob("*.py")
                 if any(isinstance(n, ast.Global) for n in ast.walk(ast.parse(p.read_text())))]
    assert offenders == []


def _private(name: str) -> bool:
    return name.startswith("_") and not name.startswith("__")


def test_no_private_name_is_imported_across_modules():
    """``from gtsweep.a import _x`` and ``a._x`` on an imported gtsweep module: a private name stays in its module
    (the package and the benchmarks; a unit test may still reach a private helper it tests)."""
    modules = _modules()
    offenders = []
    for path in [*PACKAGE.rglob("*.py"), *(PACKAGE.parent / "benchmarks").glob("*.py")]:
        tree = ast.parse(path.read_text())
        imported_modules = set()
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("gtsweep"):
                for alias in node.names:
                    if f"{node.module}.{alias.name}" in modules:
                        imported_modules.add(alias.asname or alias.name)
                    elif _private(alias.name):
                        offenders.append(f"{path.name}: from {node.module} import {alias.name}")
            elif isinstance(node, ast.Import):
                imported_modules |= {alias.asname or alias.name for alias in node.names
                                     if alias.name.startswith("gtsweep") and alias.asname}
        for node in ast.walk(tree):
            if (isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name)
                    and node.value.id in imported_modules and _private(node.attr)):
                offenders.append(f"{path.name}: {node.value.id}.{node.attr}")
    assert offenders == [], "private names used across modules:\n" + "\n".join(sorted(set(offenders)))
