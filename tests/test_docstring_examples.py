"""Every factory's docstring example runs as written and prints what it shows (doctest)."""

from __future__ import annotations

import doctest

import pytest

import trl_cartpole

# the factories: every make_* the package exports but make_q_network (make_q_actor's helper)
FACTORIES = [n for n in trl_cartpole.__all__ if n.startswith("make_") and n != "make_q_network"]


@pytest.mark.parametrize("name", FACTORIES)
def test_the_factorys_example_runs_as_written(name):
    factory = getattr(trl_cartpole, name)
    tests = doctest.DocTestFinder().find(factory, name, globs={})
    examples = [example for test in tests for example in test.examples]
    assert examples, f"{name} has no example in its docstring"
    runner = doctest.DocTestRunner(optionflags=doctest.ELLIPSIS)
    for test in tests:
        runner.run(test)
    assert runner.summarize(verbose=False).failed == 0
