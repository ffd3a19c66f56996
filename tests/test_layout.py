"""The house rules of the layout: no module over 700 lines, no import circle in the project."""

import ast
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
PACKAGES = {
    "pcvfe_drake": "pcvfe_drake",
    "systems": "pcvfe_drake.systems",
    "diagrams": "pcvfe_drake.diagrams",
}
MAX_LINES = 700


def project_modules() -> dict[str, Path]:
    """Dotted name -> file of every module of the core, ``systems/`` and ``diagrams/``."""
    mods = {}
    for folder, prefix in PACKAGES.items():
        for path in sorted((REPO / folder).rglob("*.py")):
            parts = path.relative_to(REPO / folder).with_suffix("").parts
            name = ".".join((prefix, *parts)).removesuffix(".__init__")
            mods[name] = path
    return mods


def imports_of(path: Path, mods: dict[str, Path]) -> set[str]:
    """Project modules imported anywhere in ``path`` (top level or inside functions)."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            found.add(node.module)
            found.update(f"{node.module}.{a.name}" for a in node.names)
        elif isinstance(node, ast.Import):
            found.update(a.name for a in node.names)
    return {name for name in found if name in mods}


def import_cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan, iterative)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    cycles = []
    for root in graph:
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = len(index)
        stack.append(root)
        on_stack.add(root)
        while work:
            node, children = work[-1]
            child = next(children, None)
            if child is not None:
                if child not in index:
                    index[child] = low[child] = len(index)
                    stack.append(child)
                    on_stack.add(child)
                    work.append((child, iter(sorted(graph[child]))))
                elif child in on_stack:
                    low[node] = min(low[node], index[child])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[node])
            if low[node] == index[node]:
                comp = []
                while True:
                    member = stack.pop()
                    on_stack.discard(member)
                    comp.append(member)
                    if member == node:
                        break
                if len(comp) > 1:
                    cycles.append(sorted(comp))
    return cycles


def test_no_module_over_700_lines():
    mods = project_modules()
    assert "pcvfe_drake.control.nmpc" in mods and "pcvfe_drake.systems.nmpc" in mods
    long = {
        name: n
        for name, path in mods.items()
        if (n := len(path.read_text(encoding="utf-8").splitlines())) > MAX_LINES
    }
    assert not long, f"modules over {MAX_LINES} lines (split them by responsibility): {long}"


def test_no_import_circle():
    mods = project_modules()
    graph = {}
    for name, path in mods.items():
        # A package's __init__ is imported by its modules; an import of the package itself from
        # inside it is not a circle through a module.
        graph[name] = {m for m in imports_of(path, mods) if m != name and not name.startswith(m)}
    assert import_cycles(graph) == []


def test_the_cycle_finder_finds_a_circle():
    graph = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}
    assert import_cycles(graph) == [["a", "b", "c"]]
    assert import_cycles({"a": {"b"}, "b": set()}) == []


# Packages of the core and what each may import from the others. The shared model sits below its
# two users: the context fitter (estimation) and the workbench import it, never each other.
LAYERS_FORBIDDEN = {
    "pcvfe_drake.models": ("pcvfe_drake.estimation", "pcvfe_drake.workbench"),
    "pcvfe_drake.estimation": ("pcvfe_drake.workbench",),
    "pcvfe_drake.workbench": ("pcvfe_drake.estimation",),
}


def _package_of(name: str, prefixes) -> str | None:
    return next((p for p in prefixes if name == p or name.startswith(p + ".")), None)


def test_shared_model_below_its_two_users():
    mods = project_modules()
    bad = []
    for name, path in mods.items():
        pkg = _package_of(name, LAYERS_FORBIDDEN)
        if pkg is None:
            continue
        for imported in imports_of(path, mods):
            if _package_of(imported, LAYERS_FORBIDDEN[pkg]):
                bad.append(f"{name} imports {imported}")
    assert not bad, "layer contract broken:\n" + "\n".join(sorted(bad))


def test_the_layer_check_sees_a_violation(tmp_path):
    """Imports inside functions count too (``imports_of`` walks the whole tree), so no import in
    a function can hide a cycle or a layer violation from these tests."""
    mod = tmp_path / "m.py"
    mod.write_text("def f():\n    from pcvfe_drake.workbench import ranking\n")
    mods = {"pcvfe_drake.workbench": mod, "pcvfe_drake.workbench.ranking": mod}
    assert imports_of(mod, mods) == {"pcvfe_drake.workbench", "pcvfe_drake.workbench.ranking"}
