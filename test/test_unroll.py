"""jit/unroll.py: loops over tuples of modules written out, what the modules decide decided,
the rest left as written; run here as plain Python (numba compiles the same function)."""
from __future__ import annotations

import types

import pytest

from abd_joint_sim.jit.unroll import unrolled


def _module(name, value, joints=None, constant=False):
    m = types.ModuleType(f'fake_terms.{name}')
    m.FIELDS = ((joints, ''),) if joints else ()
    m.CONSTANT = constant
    m.energy = lambda x: value * x
    m.gradient = lambda x: -value
    return m


A, B, C = _module('a', 1.0), _module('b', 10.0, 'b_joints'), _module('c', 100.0, 'c_joints', True)
LIST = (A, B, C)


def joints(term):
    return term.FIELDS[0][0] if term.FIELDS else None


class Model:
    def __init__(self, b, c):
        self.b_joints, self.c_joints = b, c


@unrolled
def total(x, m):
    E = 0.0
    for term in LIST:
        if joints(term) is None or getattr(m, joints(term)):
            if term.CONSTANT:
                E += term.gradient(x)
            else:
                E += term.energy(x)
    return E


@unrolled
def skipping(x, m):
    E = 0.0
    for term in LIST:
        if term is not A and (joints(term) is None or getattr(m, joints(term))):
            E += term.energy(x)
    return E


@unrolled
def order(x, m):
    seen = []
    for term in LIST:
        seen.append(term.energy(1.0))
    for k in range(2):              # a loop over numbers stays a loop
        seen.append(k)
    return seen


def test_loops_over_modules_are_written_out_in_the_lists_order():
    assert order(0.0, None) == [1.0, 10.0, 100.0, 0, 1]
    assert total(2.0, Model(True, True)) == 2.0 + 20.0 - 100.0


def test_what_a_module_decides_is_decided_and_the_rest_is_tested_when_run():
    # C.CONSTANT picks gradient; B and C are called only when the model has their joints
    assert total(2.0, Model(False, False)) == 2.0
    assert total(2.0, Model(True, False)) == 22.0
    assert total(2.0, Model(False, True)) == 2.0 - 100.0
    assert skipping(1.0, Model(True, True)) == 110.0
    assert skipping(1.0, Model(False, False)) == 0.0


def test_the_written_function_keeps_its_file_line_and_docstring():
    """The kernel cache locates a kernel by its file and line."""
    code = total.__code__
    assert code.co_filename == __file__
    lines = open(__file__).read().splitlines()
    assert lines[code.co_firstlineno - 1].startswith('def total(')
    for module in ('a', 'b', 'c'):
        assert module in code.co_names


def _names(code):
    return set(code.co_names) | set(code.co_varnames)


def test_written_code_reads_nothing_the_modules_decided():
    """The loop variable is gone (each copy calls its module by its global name), and so are
    the tests the modules decided and the getattr of a known name: numba compiles only the
    calls and the tests that depend on the arguments."""
    for function in (total, skipping):
        names = _names(function.__code__)
        assert not names & {'term', 'CONSTANT', 'FIELDS', 'joints', 'getattr'}, names
        assert {'b_joints', 'c_joints'} <= names


def test_an_empty_or_non_module_tuple_is_left_a_loop():
    @unrolled
    def numbers(x):
        s = 0.0
        for v in (1.0, 2.0):
            s += v * x
        return s

    assert numbers(2.0) == 6.0
    assert 'v' in numbers.__code__.co_varnames


def test_a_module_name_taken_by_something_else_is_refused():
    other = _module('total', 5.0)          # 'total' names the function above in this module
    globals()['OTHER'] = (other,)
    try:
        with pytest.raises(NameError, match='total names something else'):
            @unrolled
            def clash(x):
                E = 0.0
                for term in OTHER:          # noqa: F821
                    E += term.energy(x)
                return E
    finally:
        del globals()['OTHER']
