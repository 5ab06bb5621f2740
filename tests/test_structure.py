"""The shape of the house: the package's modules import downward only.

The import graph is read from the source with ``ast``: every ``import`` and ``from ... import`` of a
module, at module level or inside a function (a lazy import is still a dependency), relative ones
resolved. ``from package import name`` is an edge to ``package.name`` when that is a module of the
tree, else to the package itself; the import of a parent package that Python performs implicitly is
not an edge (it would make every module depend on ``sb3_cic/__init__.py``).

The layers, from the bottom:

* the library: ``sb3_cic`` (algorithms, methods, rewards, callbacks, ``common``, zoo...) and its environments
  ``sb3_cic.envs`` (the repository's ``envs/``);
* the study layer: ``sb3_cic.study`` and ``sb3_cic.protocol``, the run code that the study and
  ``sb3-cic protocol`` share (``protocol`` belongs to the study layer: a run checkpoints itself with
  ``sb3_cic.study.checkpoint`` and lays out its folder with ``sb3_cic.study.layout``); a run's result is read
  and checked here (``sb3_cic.study.run_result``, ``sb3_cic.study.results``);
* the reports over a study's runs, ``sb3_cic.report``, which read the runs that the study's records count;
* the entry points: ``sb3_cic.cli`` (every command) and ``sb3_cic.demo`` (``make demo``).

A layer imports its own and the layers below, never those above.
"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
#: each package's dotted name and its folder in the repository (``envs/`` is installed as ``sb3_cic.envs``)
PACKAGES = {"sb3_cic": "sb3_cic", "sb3_cic.envs": "envs"}
#: the study layer (see the module docstring)
STUDY = ("sb3_cic.study", "sb3_cic.protocol")
#: the reports (see the module docstring)
REPORT = ("sb3_cic.report",)
#: the entry points, above everything
ENTRY_POINTS = ("sb3_cic.cli", "sb3_cic.demo")


def module_files(root: Path = ROOT) -> dict[str, Path]:
    """Every module of :data:`PACKAGES` under ``root``, by dotted name (a package by its own name)."""
    modules = {}
    for package, folder in PACKAGES.items():
        for path in sorted((root / folder).rglob("*.py")):
            parts = (*package.split("."), *path.relative_to(root / folder).with_suffix("").parts)
            name = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
            modules[name] = path
    return modules


def _resolve(module: str, path: Path, node: ast.ImportFrom) -> str:
    if not node.level:
        return node.module or ""
    package = module.split(".") if path.name == "__init__.py" else module.split(".")[:-1]
    base = package[: len(package) - node.level + 1]
    return ".".join([*base, node.module] if node.module else base)


def imports_of(module: str, path: Path, modules: dict[str, Path]) -> set[str]:
    """The modules of the tree that ``module`` imports (module level and inside functions)."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            targets = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            source = _resolve(module, path, node)
            targets = [f"{source}.{alias.name}" if f"{source}.{alias.name}" in modules else source for alias in node.names]
        else:
            continue
        for target in targets:
            while target and target not in modules:  # ``import sb3_cic.envs.tasks.walker as w``: the module itself
                target = target.rpartition(".")[0]
            if target and target != module:
                found.add(target)
    return found


def import_graph(root: Path = ROOT) -> dict[str, set[str]]:
    """The import graph of the tree under ``root``: module -> the modules it imports."""
    modules = module_files(root)
    return {name: imports_of(name, path, modules) for name, path in modules.items()}


def find_cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The import cycles of ``graph``: the modules of each strongly connected component of more than one
    module (Tarjan's algorithm), sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    components: list[list[str]] = []

    def visit(node: str) -> None:
        index[node] = low[node] = len(index)
        stack.append(node)
        on_stack.add(node)
        for succ in sorted(graph.get(node, ())):
            if succ not in index:
                visit(succ)
                low[node] = min(low[node], low[succ])
            elif succ in on_stack:
                low[node] = min(low[node], index[succ])
        if low[node] == index[node]:
            component = []
            while True:
                member = stack.pop()
                on_stack.discard(member)
                component.append(member)
                if member == node:
                    break
            if len(component) > 1:
                components.append(sorted(component))

    for node in sorted(graph):
        if node not in index:
            visit(node)
    return components


def cycle_through(component: list[str], graph: dict[str, set[str]]) -> list[str]:
    """A path from the component's first module back to it, inside the component (breadth first)."""
    members, start = set(component), component[0]
    paths = {start: [start]}
    queue = [start]
    while queue:
        node = queue.pop(0)
        for succ in sorted(graph[node] & members):
            if succ == start:
                return paths[node] + [start]
            if succ not in paths:
                paths[succ] = paths[node] + [succ]
                queue.append(succ)
    return component


def layer(module: str) -> int:
    """0: the library, 1: the study layer, 2: the reports, 3: the entry points."""
    for floor, names in ((3, ENTRY_POINTS), (2, REPORT), (1, STUDY)):
        if any(module == name or module.startswith(f"{name}.") for name in names):
            return floor
    return 0


def test_the_graph_sees_lazy_and_relative_imports(tmp_path: Path):
    (tmp_path / "sb3_cic" / "sub").mkdir(parents=True)
    (tmp_path / "envs").mkdir()
    (tmp_path / "envs" / "__init__.py").write_text("")
    (tmp_path / "sb3_cic" / "__init__.py").write_text("from sb3_cic import a\n")
    (tmp_path / "sb3_cic" / "a.py").write_text("def f():\n    from sb3_cic.sub import b\n")
    (tmp_path / "sb3_cic" / "sub" / "__init__.py").write_text("")
    (tmp_path / "sb3_cic" / "sub" / "b.py").write_text("from .. import a\nimport numpy\n")
    graph = import_graph(tmp_path)
    assert graph["sb3_cic.a"] == {"sb3_cic.sub.b"}
    assert graph["sb3_cic.sub.b"] == {"sb3_cic.a"}
    assert find_cycles(graph) == [["sb3_cic.a", "sb3_cic.sub.b"]]
    assert cycle_through(["sb3_cic.a", "sb3_cic.sub.b"], graph) == ["sb3_cic.a", "sb3_cic.sub.b", "sb3_cic.a"]


def test_no_import_cycle():
    graph = import_graph()
    cycles = find_cycles(graph)
    described = [f"{sorted(c)} (e.g. {' -> '.join(cycle_through(c, graph))})" for c in cycles]
    assert not cycles, "import cycles: " + "; ".join(described)


def test_imports_go_downward_only():
    """The library never imports the study layer, a report or an entry point, the study layer no report or entry
    point, a report no entry point."""
    graph = import_graph()
    upward = sorted(f"{m} -> {t}" for m, targets in graph.items() for t in targets if layer(t) > layer(m))
    assert not upward, f"imports of a layer above: {upward}"


def test_the_library_does_not_import_the_study():
    """Outside the study layer (``sb3_cic.study``, and ``sb3_cic.protocol``, its run code), only the entry
    points import ``sb3_cic.study``."""
    graph = import_graph()
    offenders = sorted(
        f"{m} -> {t}" for m, targets in graph.items() for t in targets
        if layer(m) == 0 and (t == "sb3_cic.study" or t.startswith("sb3_cic.study."))
    )
    assert not offenders, offenders


def test_no_private_import_across_modules():
    """A module imports no private name (``_fmt``) of another module of the tree: what two rooms share is public."""
    modules = module_files()
    offenders = sorted(
        f"{name} imports {_resolve(name, path, node)}.{alias.name}"
        for name, path in modules.items()
        for node in ast.walk(ast.parse(path.read_text(), str(path)))
        if isinstance(node, ast.ImportFrom) and _resolve(name, path, node).startswith("sb3_cic")
        for alias in node.names
        if alias.name.startswith("_") and not alias.name.startswith("__")
    )
    assert not offenders, offenders


def test_the_wheel_lists_every_package_of_the_tree():
    """``pyproject.toml`` lists the packages explicitly (``envs/`` and ``zoo_configs/`` are installed under
    ``sb3_cic``): a new folder of modules left out of the list is missing from the wheel (tests/test_wheel.py builds
    it; this catches it in the quick tests)."""
    import tomllib

    listed = set(tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"])
    folders = {name.rpartition(".")[0] for name, path in module_files().items() if path.name != "__init__.py"}
    folders |= {name for name, path in module_files().items() if path.name == "__init__.py"}
    assert folders - listed == set(), f"packages missing from pyproject.toml: {sorted(folders - listed)}"
