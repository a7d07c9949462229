"""The scripts beside the package use it as a user would.

benchmarks/, paper_figures/ and examples/ import `jaxcaustics` (as `jc`) and its public
submodules `jaxcaustics.io`, `jaxcaustics.devices`, `jaxcaustics.reference`; benchmarks and
paper figures also `jaxcaustics.internal` (the stages' building blocks), examples never.
No deep module (`jaxcaustics.methods.choose`, ...) and no name with a leading underscore.

Everything is read with `ast`, nothing is imported: the scripts, the code they run in a
child process (a string that parses as Python and imports jaxcaustics), and the modules'
`__all__` lists, so that every `jc.<name>`, `jc.internal.<name>`, `reference.<name>`, ...
a script uses is a name its module exports (`tests/test_public_api.py` checks that each
name of an `__all__` exists).
"""

import ast
import textwrap
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PACKAGE = ROOT / "jaxcaustics"
FOLDERS = ("benchmarks", "paper_figures", "examples")

SUBMODULES = ("io", "devices", "reference", "internal")
ALLOWED = {"jaxcaustics"} | {f"jaxcaustics.{m}" for m in SUBMODULES}
EXAMPLES_ALLOWED = ALLOWED - {"jaxcaustics.internal"}
DUNDERS = {"__version__", "__file__", "__name__", "__doc__"}


def _module_file(module: str) -> Path:
    path = ROOT.joinpath(*module.split("."))
    return path / "__init__.py" if path.is_dir() else path.with_suffix(".py")


def _exports(module: str) -> set[str]:
    """The module's `__all__`, read from its file (a list or tuple of strings)."""
    tree = ast.parse(_module_file(module).read_text())
    for node in tree.body:
        targets = node.targets if isinstance(node, ast.Assign) else []
        if any(isinstance(t, ast.Name) and t.id == "__all__" for t in targets):
            return set(ast.literal_eval(node.value))
    raise AssertionError(f"{module} has no literal __all__")


EXPORTS = {m: _exports(m) for m in sorted(ALLOWED)}


def _scripts() -> list[Path]:
    return sorted(p for folder in FOLDERS for p in (ROOT / folder).rglob("*.py"))


def _trees(path: Path) -> list[ast.AST]:
    """The file, and each string in it that is Python importing jaxcaustics (a script run
    in a child process)."""
    tree = ast.parse(path.read_text(), str(path))
    trees = [tree]
    for node in ast.walk(tree):
        if isinstance(node, ast.Constant) and isinstance(node.value, str):
            if "import jaxcaustics" in node.value or "from jaxcaustics" in node.value:
                try:
                    trees.append(ast.parse(textwrap.dedent(node.value)))
                except SyntaxError:
                    pass  # prose that names an import
    return trees


def _problems(tree: ast.AST, allowed: set[str]) -> list[str]:
    """What `tree` does against the rule, as ``line: message``."""
    problems = []
    modules = {}  # local name -> the jaxcaustics module it is bound to
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                if alias.name.split(".")[0] != "jaxcaustics":
                    continue
                if alias.name not in allowed:
                    problems.append(f"{node.lineno}: import {alias.name}")
                elif alias.asname:
                    modules[alias.asname] = alias.name
                else:
                    modules["jaxcaustics"] = "jaxcaustics"
        elif isinstance(node, ast.ImportFrom) and not node.level:
            source = node.module or ""
            if source.split(".")[0] != "jaxcaustics":
                continue
            if source not in allowed:
                problems.append(f"{node.lineno}: from {source} import ...")
                continue
            for alias in node.names:
                name, bound = alias.name, alias.asname or alias.name
                sub = f"{source}.{name}"
                if name.startswith("_"):
                    problems.append(f"{node.lineno}: private name {source}.{name}")
                elif source == "jaxcaustics" and name in SUBMODULES:
                    if sub not in allowed:
                        problems.append(f"{node.lineno}: from jaxcaustics import {name}")
                    else:
                        modules[bound] = sub
                elif name != "*" and name not in EXPORTS[source]:
                    problems.append(f"{node.lineno}: {source}.{name} is not in its __all__")
    for node in ast.walk(tree):
        # the outermost attribute chains on a module name: jc.x, jc.internal.y, reference.z
        if not (isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name)):
            continue
        module = modules.get(node.value.id)
        if module is None:
            continue
        name = node.attr
        if name in DUNDERS:
            continue
        sub = f"{module}.{name}"
        if module == "jaxcaustics" and name in SUBMODULES:
            if sub not in allowed:
                problems.append(f"{node.lineno}: {node.value.id}.{name}")
        elif name not in EXPORTS[module]:
            problems.append(f"{node.lineno}: {node.value.id}.{name} is not in {module}.__all__")
    for node in ast.walk(tree):
        # jc.internal.name, jc.io.name, ...
        if not (isinstance(node, ast.Attribute) and isinstance(node.value, ast.Attribute)):
            continue
        inner = node.value
        if not isinstance(inner.value, ast.Name) or modules.get(inner.value.id) != "jaxcaustics":
            continue
        sub = f"jaxcaustics.{inner.attr}"
        if sub in allowed and sub != "jaxcaustics" and node.attr not in DUNDERS:
            if node.attr not in EXPORTS[sub]:
                problems.append(f"{node.lineno}: {inner.value.id}.{inner.attr}.{node.attr}")
    return problems


def test_the_scripts_are_found():
    scripts = _scripts()
    for folder in FOLDERS:
        assert any(p.parent.name == folder for p in scripts), folder


@pytest.mark.parametrize("path", _scripts(), ids=lambda p: str(p.relative_to(ROOT)))
def test_a_script_imports_only_the_public_modules(path):
    allowed = EXAMPLES_ALLOWED if path.parent.name == "examples" else ALLOWED
    problems = [p for tree in _trees(path) for p in _problems(tree, allowed)]
    assert not problems, f"{path.relative_to(ROOT)}:\n" + "\n".join(problems)


def test_the_checker_sees_what_it_should():
    bad = """
import jaxcaustics as jc
import jaxcaustics.methods.registry
from jaxcaustics.methods.choose import resolve_knobs
from jaxcaustics.internal import _private
from jaxcaustics import internal as ji
from jaxcaustics import render, no_such_name
jc.internal.two_pass
jc.internal.no_such_name
jc.no_such_name
jc.methods
ji.no_such_name
jc.render
"""
    for allowed, lines in (
        (EXAMPLES_ALLOWED, [3, 4, 5, 6, 7, 8, 9, 10, 11]),
        (ALLOWED, [3, 4, 5, 7, 9, 10, 11, 12]),  # benchmarks may use internal
    ):
        problems = _problems(ast.parse(bad), allowed)
        assert sorted(int(p.split(":")[0]) for p in problems) == lines, problems
