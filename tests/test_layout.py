"""The house rules of the code base, read from the source: the product never imports the lab, the
package has no import cycle, and every product module serves a user journey."""

from __future__ import annotations

import ast
import re
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
MODULE = r"(dcm(?:\.\w+)+)(?::\w+)?"  # a string naming a module (or module:attribute) loaded by name

# The user journeys: the two root entries and the console scripts' modules.
ENTRY_MODULES = ("train", "tune", "dcm.data.generate", "dcm.data.import_logs", "dcm.data.sim_logs", "dcm.data.merge",
                 "dcm.data.inspect", "dcm.evaluate", "dcm.sim.render", "dcm.models.checkpoint", "dcm.training.export",
                 "dcm.training.distill", "dcm.models.references")


def _module_name(path: Path) -> str:
    parts = path.relative_to(REPO).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _modules(*roots: str) -> dict[str, Path]:
    found = {}
    for root in roots:
        target = REPO / root
        paths = [target] if target.suffix == ".py" else sorted(target.rglob("*.py"))
        found.update({_module_name(path): path for path in paths})
    return found


def _imports(path: Path, known: set[str]) -> set[str]:
    """Modules of ``known`` that ``path`` imports, at any depth (lazy imports count), or names in a string
    (modules loaded by name)."""
    tree = ast.parse(path.read_text())
    names: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names.add(node.module)
            names.update(f"{node.module}.{alias.name}" for alias in node.names)
        elif isinstance(node, ast.Constant) and isinstance(node.value, str) and (match := re.fullmatch(MODULE, node.value)):
            names.add(match.group(1))
    return {name for name in names if name in known}


def _graph(modules: dict[str, Path]) -> dict[str, set[str]]:
    known = set(modules)
    return {name: _imports(path, known) - {name} for name, path in modules.items()}


def test_product_never_imports_the_lab():
    product = _modules("dcm", "train.py", "tune.py")
    offenders = []
    for name, path in product.items():
        for node in ast.walk(ast.parse(path.read_text())):
            module = (node.names[0].name if isinstance(node, ast.Import)
                      else node.module if isinstance(node, ast.ImportFrom) else None)
            if module and (module == "studies" or module.startswith("studies.")):
                offenders.append(f"{name} imports {module}")
    assert not offenders, offenders


def test_no_import_cycles_in_the_product():
    graph = _graph(_modules("dcm"))
    # A package's __init__ re-exporting its children is not a cycle of logic: drop parent -> child arrows.
    graph = {name: {dep for dep in deps if not dep.startswith(name + ".")} for name, deps in graph.items()}
    cycles = []
    state: dict[str, int] = {}

    def visit(node: str, stack: list[str]) -> None:
        state[node] = 1
        for dep in sorted(graph[node]):
            if state.get(dep) == 1:
                cycles.append(" -> ".join(stack[stack.index(dep):] + [dep]))
            elif dep not in state:
                visit(dep, stack + [dep])
        state[node] = 2

    for node in sorted(graph):
        if node not in state:
            visit(node, [node])
    assert not cycles, cycles


def test_every_product_module_serves_a_journey():
    modules = _modules("dcm", "train.py", "tune.py")
    graph = _graph(modules)
    for name in list(graph):  # importing a.b.c runs a and a.b
        parts = name.split(".")
        graph[name] |= {".".join(parts[:i]) for i in range(1, len(parts))} & set(modules)
    reached, todo = set(), [name for name in ENTRY_MODULES if name in modules]
    missing_entries = [name for name in ENTRY_MODULES if name not in modules]
    while todo:
        name = todo.pop()
        if name not in reached:
            reached.add(name)
            todo.extend(graph[name])
    unreached = sorted(set(modules) - reached)
    assert not missing_entries, f"entry modules not found: {missing_entries}"
    assert not unreached, f"modules no user journey reaches (move them to studies/): {unreached}"


def test_console_scripts_point_at_entries_that_exit_cleanly():
    """A console script exits with its function's return value: an entry must return None (or an int)."""
    import importlib
    import inspect
    import tomllib

    scripts = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]["scripts"]
    assert {"dcm-generate", "dcm-train", "dcm-tune", "dcm-evaluate", "dcm-import-logs"} <= set(scripts)
    for name, target in scripts.items():
        module, function = target.split(":")
        entry = getattr(importlib.import_module(module), function)
        returns = inspect.signature(entry).return_annotation
        assert returns in (None, "None", int, "int", inspect.Signature.empty), f"{name} -> {target} returns {returns}"
