"""Docstring examples run as written (doctest), so an example a user copies works."""

import doctest
import importlib
import pkgutil

import pytest

import isettorch

MODULES = sorted(m.name for m in pkgutil.walk_packages(isettorch.__path__, "isettorch.")
                 if not m.name.startswith("isettorch.commands."))


@pytest.mark.parametrize("name", MODULES)
def test_docstring_examples_run(name):
    module = importlib.import_module(name)
    flags = doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE
    finder = doctest.DocTestFinder()
    runner = doctest.DocTestRunner(optionflags=flags)
    for test in finder.find(module, name, globs={"torch": importlib.import_module("torch"), **vars(module)}):
        runner.run(test)
    result = runner.summarize(verbose=False)
    assert result.failed == 0, f"{result.failed} docstring example(s) of {name} failed (see the output above)"
