"""Property tests of the fixed-point codec."""

import math

import numpy as np
import pytest
from hypothesis import given, strategies as st
from hypothesis.extra.numpy import arrays

from ase_reversible import QuantumRangeError
from ase_reversible import fixedpoint as fp

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


@given(arrays(np.int64, 6, elements=st.integers(-2**52, 2**52)),
       arrays(np.float64, 6, elements=st.floats(-2.0**52, 2.0**52)))
def test_add_rounded_is_undone_by_the_negated_increment(ints, y):
    forward = fp.add_rounded(ints, y.copy(), 'x', 1.0)
    back = fp.add_rounded(forward, -y, 'x', 1.0)
    assert np.array_equal(back, ints)


@given(st.integers(-fp.LIMIT + 1, fp.LIMIT - 1),
       st.floats(-2.0**60, 2.0**60, allow_nan=False))
def test_add_rounded_refuses_to_leave_the_range(start, increment):
    ints = np.array([start], dtype=np.int64)
    total = start + int(np.rint(increment))
    if abs(int(np.rint(increment))) < fp.LIMIT and abs(total) < fp.LIMIT:
        assert fp.add_rounded(ints, np.array([increment]), 'x', 1.0)[0] == total
    else:
        with pytest.raises(QuantumRangeError):
            fp.add_rounded(ints, np.array([increment]), 'x', 1.0)
    assert ints[0] == start  # the input is never modified


@pytest.mark.parametrize('bad', [np.nan, np.inf, -np.inf])
def test_non_finite_increments_are_refused(bad):
    with pytest.raises(QuantumRangeError, match='not finite'):
        fp.add_rounded(np.zeros(3, np.int64), np.array([0.0, bad, 1.0]),
                       'momentum', 1.0)


@given(st.floats(min_value=1e-200, max_value=1e200))
def test_quantum_for_is_the_smallest_sufficient_power_of_two(max_abs):
    q = fp.quantum_for(max_abs)
    assert math.frexp(q)[0] == 0.5
    assert max_abs < fp.LIMIT * q
    assert max_abs >= fp.LIMIT * q / 2


@pytest.mark.parametrize('q', [0.0, -1.0, 3e-12, np.inf, np.nan])
def test_grid_rejects_quanta_that_are_not_powers_of_two(q):
    with pytest.raises(ValueError, match='power of two'):
        fp.Grid(q, 2.0**-40)
