"""The package's own imports: all at the top of a module, and no cycle among them.

Reads every module of `jaxcaustics` with `ast` (nothing is imported), so that the
dependency graph is the one the files show: a function-local import hides an edge (and
is how a cycle is usually papered over), and a cycle means two modules that cannot be
read, tested or moved apart.
"""

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parent.parent / "jaxcaustics"


def _module_name(path: Path) -> str:
    parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _is_module(name: str) -> bool:
    path = PACKAGE.parent.joinpath(*name.split("."))
    return path.with_suffix(".py").is_file() or (path / "__init__.py").is_file()


def _targets(node, importer: str, is_package: bool) -> list[str]:
    """The package modules an import statement reads (a name imported from a package
    that is a module of its own counts as that module)."""
    if isinstance(node, ast.Import):
        return [a.name for a in node.names if a.name.split(".")[0] == "jaxcaustics"]
    if node.level:
        base = importer.split(".")
        base = base if is_package else base[:-1]
        base = base[: len(base) - (node.level - 1)]
        source = ".".join(base + ([node.module] if node.module else []))
    else:
        source = node.module or ""
    if source.split(".")[0] != "jaxcaustics":
        return []
    found = []
    for alias in node.names:
        sub = f"{source}.{alias.name}"
        found.append(sub if _is_module(sub) else source)
    return found


def _imports():
    """``{module: (top-level targets, [(line, target) of function-local imports])}``."""
    graph = {}
    for path in sorted(PACKAGE.rglob("*.py")):
        name = _module_name(path)
        tree = ast.parse(path.read_text(), str(path))
        is_package = path.name == "__init__.py"
        top, local = set(), []
        top_nodes = set()
        for node in tree.body:
            for inner in ast.walk(node) if isinstance(node, ast.If) else [node]:
                if isinstance(inner, (ast.Import, ast.ImportFrom)):
                    top_nodes.add(id(inner))
                    top.update(_targets(inner, name, is_package))
        for node in ast.walk(tree):
            if isinstance(node, (ast.Import, ast.ImportFrom)) and id(node) not in top_nodes:
                local += [(node.lineno, t) for t in _targets(node, name, is_package)]
        graph[name] = (top - {name}, local)
    return graph


def test_no_function_local_import_of_the_package():
    local = {
        f"{module}:{line} imports {target}"
        for module, (_, found) in _imports().items()
        for line, target in found
    }
    assert not local, "imports inside functions:\n" + "\n".join(sorted(local))


def test_no_import_cycle():
    graph = {m: top for m, (top, _) in _imports().items()}
    # the package's __init__ re-exports its modules: edges into it are what can cycle
    cycles = []
    state = {}

    def visit(module, path):
        state[module] = "open"
        for target in sorted(graph.get(module, ())):
            if state.get(target) == "open":
                cycles.append(path[path.index(target) :] + [target])
            elif target not in state:
                visit(target, path + [target])
        state[module] = "done"

    for module in sorted(graph):
        if module not in state:
            visit(module, [module])
    assert not cycles, "import cycles:\n" + "\n".join(" -> ".join(c) for c in cycles)


def test_the_walk_sees_the_package():
    graph = _imports()
    assert "jaxcaustics.methods.render" in graph and "jaxcaustics.reference" in graph
    assert "jaxcaustics.methods.twopass" in graph["jaxcaustics.methods.registry"][0]


# the stages of the data flow, in order: a module imports only from its own group or an
# earlier stage (scene -> trace -> reconstruct -> methods -> inverse -> cli)
STAGES = [
    ("_checks", "_warnings"),
    ("devices", "io", "reference"),
    ("scene",),
    ("trace",),
    ("reconstruct",),
    ("methods.base",),
    ("methods.twopass", "methods.triangles", "methods.caustic_map", "methods.spot_lights"),
    ("methods",),
    ("inverse",),
    ("internal",),  # the building blocks, no promise
    ("",),  # the package's __init__: the public names
    ("cli",),  # the command, a user of the public names
    ("__main__",),
]


def _group(module: str) -> tuple[int, str]:
    """``(stage, group)`` of a package module: the longest prefix listed in `STAGES`."""
    name = module.removeprefix("jaxcaustics").removeprefix(".")
    best = None
    for rank, groups in enumerate(STAGES):
        for group in groups:
            if name == group or (group and name.startswith(group + ".")):
                if best is None or len(group) > len(best[1]):
                    best = (rank, group)
    assert best is not None, f"{module} is in no stage of STAGES"
    return best


def test_each_stage_imports_only_earlier_stages():
    """The tree shows the data flow: a scene knows nothing of tracing, a method nothing of
    another method or of the inverse problems, and so on."""
    wrong = []
    for module, (top, _) in _imports().items():
        rank, group = _group(module)
        for target in top:
            target_rank, target_group = _group(target)
            if target_group != group and target_rank >= rank:
                wrong.append(f"{module} -> {target}")
    assert not wrong, "imports against the data flow:\n" + "\n".join(wrong)


def test_the_public_surface_is_all():
    """Every name the package exports is in `__all__`, and every name there exists."""
    import inspect

    import jaxcaustics as jc

    public = {n for n, v in vars(jc).items() if not n.startswith("_") and not inspect.ismodule(v)}
    assert public == set(jc.__all__)
    assert len(jc.__all__) == len(set(jc.__all__))
