"""Property tests of the fixed-point codec."""

import math

import numpy as np
import pytest
from hypothesis import given, strategies as st
from hypothesis.extra.numpy import arrays

from ase_reversible import QuantumRangeError
from ase_reversible.core import codec as fp
from ase_reversible.core.quanta import Grid
from ase_reversible.core.variables import ExactVariable

finite = st.floats(min_value=-1e300, max_value=1e300, allow_nan=False)
exponents = st.integers(min_value=-60, max_value=10)


@given(finite)
def test_rint_is_odd(y):
    assert np.rint(-y) == -np.rint(y)


@given(st.floats(allow_nan=False, allow_infinity=False, min_value=-1e15,
                 max_value=1e15))
def test_floor_half_up_is_not_odd_counterexample_exists(y):
    # The trap the codec avoids: floor(y + 0.5) differs from odd rounding
    # exactly at negative half-integers.
    y = math.floor(y) + 0.5
    assert math.floor(-y + 0.5) != -math.floor(y + 0.5)


@given(arrays(np.int64, st.integers(1, 20),
              elements=st.integers(-fp.LIMIT + 1, fp.LIMIT - 1)), exponents)
def test_decode_is_exact_and_encode_inverts_it(ints, exponent):
    q = math.ldexp(1.0, exponent)
    values = fp.decode(ints, q)
    # Exact: each float is the integer times q, recovered by division.
    assert np.array_equal(values / q, ints.astype(np.float64))
    assert np.array_equal(fp.encode(values, q, 'x'), ints)


@given(st.lists(finite, min_size=1, max_size=10), exponents)
def test_encode_moves_by_at_most_half_a_quantum(values, exponent):
    q = math.ldexp(1.0, exponent)
    values = np.array(values)
    with np.errstate(over='ignore'):
        outside = np.any(~(np.abs(values / q) < fp.LIMIT))
    if outside:
        with pytest.raises(QuantumRangeError):
            fp.encode(values, q, 'x')
        return
    ints = fp.encode(values, q, 'x')
    assert np.all(np.abs(fp.decode(ints, q) - values) <= 0.5 * q)


def rounded(y):
    return np.rint(np.array(y, dtype=np.float64))


def assert_holds(variable, ints):
    assert np.array_equal(variable.ints, ints)
    # The float image is exact: the counts times the quantum.
    assert np.array_equal(variable.floats / variable.quantum,
                          np.asarray(ints, dtype=np.float64))


@given(arrays(np.int64, 6, elements=st.integers(-2**52, 2**52)),
       arrays(np.float64, 6, elements=st.floats(-2.0**51, 2.0**51)),
       exponents)
def test_a_rounded_increment_is_undone_by_the_negated_one(ints, y, exponent):
    variable = ExactVariable('x', ints, math.ldexp(1.0, exponent))
    variable.add_integers(rounded(y))
    variable.add_integers(rounded(-y))
    assert_holds(variable, ints)


@given(st.integers(-fp.LIMIT + 1, fp.LIMIT - 1),
       st.floats(-2.0**60, 2.0**60, allow_nan=False))
def test_an_update_never_leaves_the_range(start, increment):
    variable = ExactVariable('x', np.array([start]), 1.0)
    step = int(np.rint(increment))
    if abs(step) < fp.LIMIT and abs(start + step) < fp.LIMIT:
        variable.add_integers(rounded([increment]))
        assert_holds(variable, [start + step])
    else:
        with pytest.raises(QuantumRangeError):
            variable.add_integers(rounded([increment]))
        assert_holds(variable, [start])  # nothing was committed


def test_the_range_is_enforced_over_many_updates():
    variable = ExactVariable('x', np.zeros(2, np.int64), 1.0)
    step = rounded([2.0**50, -(2.0**50)])
    for k in range(1, 8):
        variable.add_integers(step)
    with pytest.raises(QuantumRangeError, match='outside'):
        variable.add_integers(step)  # would reach 8 * 2**50 == LIMIT
    assert_holds(variable, [7 * 2**50, -7 * 2**50])


def test_back_and_forth_updates_never_raise_a_false_alarm():
    # The running bound on |counts| grows with every update; it must be
    # replaced by the true maximum rather than raise.
    variable = ExactVariable('x', np.array([3, -3]), 1.0)
    for _ in range(50):
        variable.add_integers(rounded([2.0**52, 2.0**52]))
        variable.add_integers(rounded([-(2.0**52), -(2.0**52)]))
    assert_holds(variable, [3, -3])


@pytest.mark.parametrize('bad', [np.nan, np.inf, -np.inf])
def test_non_finite_increments_are_refused(bad):
    variable = ExactVariable('momentum', np.zeros(3, np.int64), 1.0)
    with pytest.raises(QuantumRangeError, match='not finite'):
        variable.add_integers(np.array([0.0, bad, 1.0]))
    assert_holds(variable, [0, 0, 0])


@given(st.lists(arrays(np.float64, 4, elements=st.floats(-1e6, 1e6)),
                min_size=1, max_size=6))
def test_rollback_returns_to_the_checkpoint_after_any_updates(increments):
    start = np.arange(4)
    variable = ExactVariable('x', start, 2.0**-3)
    variable.add_integers(rounded([1, 2, 3, 4]))
    variable.checkpoint()
    expected = variable.ints.copy()
    for y in increments:  # more updates than there are spare buffers
        variable.add_integers(rounded(y))
    variable.rollback()
    assert_holds(variable, expected)


@given(st.floats(min_value=1e-200, max_value=1e200))
def test_quantum_for_is_the_smallest_sufficient_power_of_two(max_abs):
    q = fp.quantum_for(max_abs)
    assert math.frexp(q)[0] == 0.5
    assert max_abs < fp.LIMIT * q
    assert max_abs >= fp.LIMIT * q / 2


@pytest.mark.parametrize('q', [0.0, -1.0, 3e-12, np.inf, np.nan])
def test_grid_rejects_quanta_that_are_not_powers_of_two(q):
    with pytest.raises(ValueError, match='power of two'):
        Grid(q, 2.0**-40)
