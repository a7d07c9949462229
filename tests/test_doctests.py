"""The examples in the package's docstrings (``>>>`` lines) run as doctests in the
default test run: each module's examples with a fresh namespace holding ``jc``,
``jax``, ``jnp`` and ``np``."""

import doctest
import importlib
import pkgutil

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxcaustics as jc

# every module of the package but the command's entry point (importing it runs the CLI)
MODULES = sorted(
    m.name
    for m in pkgutil.walk_packages(jc.__path__, "jaxcaustics.")
    if not m.name.endswith("__main__")
)
FLAGS = doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE


def _examples(name):
    module = importlib.import_module(name)
    finder = doctest.DocTestFinder(exclude_empty=True)
    globs = {"jc": jc, "jax": jax, "jnp": jnp, "np": np}
    return [t for t in finder.find(module, name, globs=globs) if t.examples]


WITH_EXAMPLES = [name for name in MODULES if _examples(name)]


def test_the_public_functions_carry_examples():
    """Not a vacuous run: the entry points a user meets first show how they are called."""
    tests = {t.name for name in WITH_EXAMPLES for t in _examples(name)}
    for wanted in (
        "jaxcaustics.methods.render.render",
        "jaxcaustics.methods.registry.method_for",
        "jaxcaustics.scene.waves.wave_heights",
        "jaxcaustics.methods.choose.image_error",
    ):
        assert wanted in tests


@pytest.mark.parametrize("name", WITH_EXAMPLES)
def test_docstring_examples(name):
    runner = doctest.DocTestRunner(optionflags=FLAGS)
    for test in _examples(name):
        runner.run(test)
    result = runner.summarize(verbose=False)
    assert result.failed == 0, f"{result.failed} of {result.attempted} examples failed in {name}"
