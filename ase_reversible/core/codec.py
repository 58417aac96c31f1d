"""The fixed-point codec: the one owner of quanta, rounding and range.

A real value ``v`` is stored as the integer ``I = rint(v / q)`` for a quantum
``q``.  Quanta are powers of two and integers are kept below ``LIMIT = 2**53``
in magnitude, so that

* ``I * q`` is exact in float64: the values shown on the Atoms object (and
  in every trajectory frame) are exact images of the integers, and ``v / q``
  gives the integer back exactly;
* the sum of two in-range integers never wraps around in int64.

Every update adds ``round_odd(y)`` for a float increment ``y`` in quanta.
``np.rint`` rounds half to even, which is odd -- ``rint(-y) == -rint(y)`` --
and odd rounding is what makes a sub-step with ``-h`` undo one with ``h``
exactly (Stam, "An Exact Bitwise Reversible Integrator"; Rein & Tamayo
2018).  ``floor(y + 0.5)`` is not odd: it rounds -0.5 and 0.5 both up.

Array naming: a suffix gives the shape -- ``_nc`` is ``[n_atoms, 3]``
(Cartesian per atom), ``_n1`` is ``[n_atoms, 1]`` -- and a leading ``i`` marks
an int64 array counted in quanta (``ix_nc``, ``ip_nc``).
"""

from __future__ import annotations

import math

import numpy as np

from ..errors import QuantumRangeError

#: Exclusive bound on the magnitude of every stored integer.
LIMIT = 2**53
_FLIMIT = float(LIMIT)


def check_quantum(q, name='quantum') -> float:
    """Return ``q`` as a float if it is a positive, finite power of two."""
    q = float(q)
    if not (math.isfinite(q) and q > 0 and math.frexp(q)[0] == 0.5):
        raise ValueError(
            f'{name} must be a positive power of two (such as 2.0**-40), '
            f'got {q!r}: only then are the float64 values on the Atoms '
            'object exact images of the integers.')
    return q


def quantum_for(max_abs: float) -> float:
    """Smallest power-of-two quantum whose range exceeds ``max_abs``.

    The range is ``LIMIT * quantum``; ``max_abs`` and the result share a
    unit (Å for positions, amu Å / ASE time unit for momenta).
    """
    if not (math.isfinite(max_abs) and max_abs > 0):
        raise ValueError(f'range must be positive and finite, got {max_abs!r}')
    exponent = math.frexp(max_abs)[1]  # max_abs < 2**exponent
    return math.ldexp(1.0, exponent - 53)


def power_of_two_below(value: float) -> float:
    """The largest power of two at most ``value`` (positive, finite): the
    scale a quantum is taken below, for a spread or a time step."""
    return math.ldexp(1.0, math.frexp(value)[1] - 1)


def value_range(quantum: float) -> float:
    """Largest representable ``|value|`` (exclusive) for ``quantum``."""
    return _FLIMIT * quantum


def round_odd(y, out=None):
    """``rint(y)``, ties to even: odd, ``round_odd(-y) == -round_odd(y)``.

    The one rounding rule of every exact update.  ``y``: float array of
    any shape, in quanta; ``out`` may be ``y`` itself.
    """
    return np.rint(y, out=out)


def guard_band_crossed(y, rounded, bound) -> bool:
    """Whether an error below ``bound`` could change ``round_odd(y)``.

    ``y`` (float, any shape, in quanta; overwritten as scratch) and
    ``rounded = round_odd(y)``.  True if some element lies within
    ``bound`` of a half-integer, where noise of that size could move it
    across the rounding boundary.  NaN compares False: non-finite input
    is not flagged here but refused where it is added.
    """
    np.subtract(y, rounded, out=y)
    np.abs(y, out=y)
    return bool(y.max(initial=0.0) > 0.5 - bound)


def encode(values, quantum: float, what: str) -> np.ndarray:
    """Snap float ``values`` to the grid: int64 ``rint(values / quantum)``.

    ``values``: an array of any shape, in the unit of ``quantum``; the
    result has the same shape.  Moves each value by at most half a
    quantum.  ``what`` names the values in error messages.  Raises
    :class:`~ase_reversible.QuantumRangeError` for values outside the range.
    """
    with np.errstate(over='ignore', invalid='ignore'):
        y = np.asarray(values, dtype=np.float64) / quantum
    round_odd(y, out=y)
    check_range(y, what, quantum, 'Choose a larger quantum.')
    return y.astype(np.int64)


def decode(ints, quantum: float, out=None) -> np.ndarray:
    """Exact float64 image ``ints * quantum``, same shape as ``ints``.

    Exact because the quantum is a power of two and ``|ints| < LIMIT``.
    """
    return np.multiply(ints, quantum, out=out, dtype=np.float64)


def on_grid(values, quantum: float) -> bool:
    """Whether every element of ``values`` is a whole number of quanta.

    Exact: division by a power of two is.  A frame the integrator wrote is
    on its grid; one edited since (new velocities, moved atoms) is not.
    """
    counts = np.asarray(values, dtype=np.float64) / quantum
    return bool(np.array_equal(np.rint(counts), counts))


def check_range(a: np.ndarray, what: str, quantum: float, advice: str):
    """Raise :class:`~ase_reversible.QuantumRangeError` naming the first
    atom (row) of ``a`` (in quanta) that is non-finite or not below
    ``LIMIT``."""
    if a.size == 0:
        return
    # max() propagates NaN and NaN < LIMIT is False: one pass catches both.
    if np.abs(a).max() < LIMIT:
        return
    bad = ~(np.abs(a) < LIMIT)
    atom = int(np.argwhere(bad.reshape(len(a), -1).any(axis=1))[0, 0])
    if not np.all(np.isfinite(a)):
        raise QuantumRangeError(f'{what} of atom {atom} is not finite. '
                                f'{advice}')
    raise QuantumRangeError(
        f'{what} of atom {atom} is outside the fixed-point range '
        f'(|value| < {_FLIMIT * quantum:.4g} with quantum {quantum:.4g}). '
        f'{advice}')
