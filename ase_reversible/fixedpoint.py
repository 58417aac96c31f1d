"""Fixed-point codec: int64 grids for positions and momenta.

A real value ``v`` is stored as the integer ``I = rint(v / q)`` for a quantum
``q``.  Quanta are powers of two and integers are kept below ``LIMIT = 2**53``
in magnitude, so that

* ``I * q`` is exact in float64: the positions and momenta on the Atoms
  object (and in every trajectory frame) are exact images of the integers,
  and ``v / q`` gives the integer back exactly;
* the sum of two in-range integers never wraps around in int64.

Updates add ``rint(y)`` for a float increment ``y`` (in quanta).  ``np.rint``
rounds half to even, which is odd -- ``rint(-y) == -rint(y)`` -- and odd
rounding is what makes a step with ``-h`` undo a step with ``h`` exactly
(Stam, "An Exact Bitwise Reversible Integrator"; Rein & Tamayo 2018).

Array naming: a suffix gives the shape -- ``_nc`` is ``[n_atoms, 3]``
(Cartesian per atom), ``_n1`` is ``[n_atoms, 1]`` -- and a leading ``i`` marks
an int64 array counted in quanta (``ix_nc``, ``ip_nc``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from ase import units

from .errors import QuantumRangeError

#: Exclusive bound on the magnitude of every stored integer.
LIMIT = 2**53
_FLIMIT = float(LIMIT)

#: Default head room of the position range over the system's extent.
POSITION_ROOM = 2.0**10
#: Default head room of the momentum range over the reference momentum.
MOMENTUM_ROOM = 2.0**8
#: Temperature (K) below which the momentum scale is not allowed to shrink.
MOMENTUM_TEMPERATURE_FLOOR = 1000.0


class FixedPointState(NamedTuple):
    """Exact dynamical state.  Arrays are never modified in place.

    Attributes
    ----------
    ix_nc : int64 array [n_atoms, 3]
        Positions in units of ``Grid.position_quantum``.
    ip_nc : int64 array [n_atoms, 3]
        Momenta in units of ``Grid.momentum_quantum``.
    """

    ix_nc: np.ndarray
    ip_nc: np.ndarray


@dataclass(frozen=True)
class Grid:
    """The two quanta of the fixed-point representation.

    Attributes
    ----------
    position_quantum : float
        Å; a power of two.  Positions must stay below
        ``LIMIT * position_quantum`` in magnitude.
    momentum_quantum : float
        ASE momentum units (amu Å / ASE time unit); a power of two.
    """

    position_quantum: float
    momentum_quantum: float

    def __post_init__(self):
        for name in ('position_quantum', 'momentum_quantum'):
            check_quantum(getattr(self, name), name)

    @property
    def position_range(self) -> float:
        """Largest representable ``|position|`` (exclusive), Å."""
        return _FLIMIT * self.position_quantum

    @property
    def momentum_range(self) -> float:
        """Largest representable ``|momentum|`` (exclusive), ASE units."""
        return _FLIMIT * self.momentum_quantum

    def todict(self) -> dict:
        """``{'position_quantum': ..., 'momentum_quantum': ...}`` (floats)."""
        return {'position_quantum': self.position_quantum,
                'momentum_quantum': self.momentum_quantum}


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


def choose_position_quantum(positions_nc, cell, pbc,
                            room: float = POSITION_ROOM) -> float:
    """Position quantum (Å) for a system, leaving ``room`` times its size.

    ``positions_nc`` is ``[n_atoms, 3]`` (Å), ``cell`` ``[3, 3]`` (Å), ``pbc``
    three booleans.  The size is the largest ``|coordinate|`` of the atoms or
    of the periodic cell vectors' span, and at least 1 Å.  With the default room of 1024 a
    20 Å system gets a quantum of 2**-38 Å (3.6e-12 Å) and can spread to
    about 3e4 Å before an atom leaves the range.
    """
    size = 1.0
    if len(positions_nc):
        size = max(size, float(np.abs(positions_nc).max()))
    cell = np.asarray(cell)
    if np.any(pbc):
        size = max(size, float(np.abs(cell[np.asarray(pbc)]).sum(axis=0).max()))
    return quantum_for(size * room)


def momentum_scale(masses_n, momenta_nc,
                   temperature_floor: float = MOMENTUM_TEMPERATURE_FLOOR
                   ) -> float:
    """The momentum a grid must resolve, amu Å / ASE time unit.

    The largest ``|momentum|`` component of ``momenta_nc`` ``[n_atoms, 3]``, or
    the thermal momentum ``sqrt(m kB T)`` of the heaviest atom (``masses_n``
    ``[n_atoms]``, amu) at ``temperature_floor`` K, whichever is larger.
    """
    scale = math.sqrt(float(np.max(masses_n)) * units.kB * temperature_floor)
    if len(momenta_nc):
        scale = max(scale, float(np.abs(momenta_nc).max()))
    return scale


def choose_momentum_quantum(masses_n, momenta_nc,
                            room: float = MOMENTUM_ROOM,
                            temperature_floor: float =
                            MOMENTUM_TEMPERATURE_FLOOR) -> float:
    """Momentum quantum (ASE units) leaving ``room`` times the momentum scale.

    ``masses_n`` is ``[n_atoms]`` (amu), ``momenta_nc`` ``[n_atoms, 3]``
    (amu Å / ASE time unit); the scale is :func:`momentum_scale`.  For
    argon near 100 K this gives 2**-44 (5.7e-14 amu Å / ASE time), a
    resolution of ~1e-13 of a thermal momentum.
    """
    return quantum_for(momentum_scale(masses_n, momenta_nc,
                                      temperature_floor) * room)


#: Fewest significant bits a momentum quantum must leave of the momentum
#: scale.  The default grid leaves about 44; a quantum with 12 resolves a
#: thermal momentum to 2.4e-4, and rounding errors of that size in every
#: kick swamp the integrator's own energy error.
MIN_MOMENTUM_BITS = 12
#: Largest relative change of the kinetic energy that snapping the momenta
#: to the grid may cause.  The default grid changes it by ~1e-13.
MAX_SNAP_KINETIC_CHANGE = 1e-6


def momentum_resolution_problem(masses_n, momenta_nc, quantum: float):
    """Why ``quantum`` is too coarse for these momenta, or None if it is not.

    ``masses_n`` ``[n_atoms]`` (amu), ``momenta_nc`` ``[n_atoms, 3]`` (amu Å
    / ASE time unit, constraints already applied), ``quantum`` in the same
    unit.  The quantum is too coarse if snapping the momenta to it changes
    the kinetic energy by more than ``MAX_SNAP_KINETIC_CHANGE`` of itself,
    or if it leaves fewer than ``MIN_MOMENTUM_BITS`` bits of
    :func:`momentum_scale`.  Returns a sentence with the numbers.
    """
    momenta_nc = np.asarray(momenta_nc, dtype=np.float64)
    m_n1 = np.asarray(masses_n, dtype=np.float64)[:, None]
    kinetic = 0.5 * float(np.sum(momenta_nc**2 / m_n1))
    snapped_nc = np.rint(momenta_nc / quantum) * quantum
    snapped = 0.5 * float(np.sum(snapped_nc**2 / m_n1))
    scale = momentum_scale(masses_n, momenta_nc)
    bits = math.log2(scale / quantum)
    reasons = []
    if abs(snapped - kinetic) > MAX_SNAP_KINETIC_CHANGE * kinetic:
        reasons.append(
            f'snapping the momenta to it changes the kinetic energy from '
            f'{kinetic:.6g} eV to {snapped:.6g} eV (by '
            f'{(snapped - kinetic) / kinetic:+.2g} of itself; at most '
            f'{MAX_SNAP_KINETIC_CHANGE:g} is allowed)')
    if bits < MIN_MOMENTUM_BITS:
        reasons.append(
            f'it leaves {max(bits, 0.0):.1f} significant bits of the '
            f'momentum scale {scale:.3g} (the largest momentum, or the '
            f'thermal momentum of the heaviest atom at '
            f'{MOMENTUM_TEMPERATURE_FLOOR:g} K), fewer than the '
            f'{MIN_MOMENTUM_BITS} needed')
    return ' and '.join(reasons) or None


def encode(values, quantum: float, what: str) -> np.ndarray:
    """Snap float ``values`` to the grid: int64 ``rint(values / quantum)``.

    ``values``: an array of any shape, in the unit of ``quantum``; the
    result has the same shape.  Moves each value by at most half a
    quantum.  ``what`` names the values in error messages.  Raises
    :class:`QuantumRangeError` for values outside the range.
    """
    with np.errstate(over='ignore', invalid='ignore'):
        y = np.asarray(values, dtype=np.float64) / quantum
    np.rint(y, out=y)
    _check_range(y, what, quantum, 'Choose a larger quantum.')
    return y.astype(np.int64)


def decode(ints, quantum: float, out=None) -> np.ndarray:
    """Exact float64 image ``ints * quantum``, same shape as ``ints``.

    Exact because the quantum is a power of two and ``|ints| < LIMIT``.
    """
    return np.multiply(ints, quantum, out=out, dtype=np.float64)


class FixedPointArray:
    """One fixed-point variable ``[n_atoms, 3]`` updated without allocations.

    Holds the int64 counts and their exact float64 image ``counts *
    quantum``.  Three buffers rotate -- the value at the last
    :meth:`checkpoint`, the current value, and the one being written -- so
    an update never overwrites the checkpoint, and :meth:`rollback` puts it
    back without copying anything.

    Each buffer carries an upper bound on its largest ``|count|``: an update
    adds the increment's largest magnitude to it and checks the sum itself
    only when the bound reaches ``LIMIT``.  With the default head room that
    is rare, so most updates skip two passes over the array.

    Parameters
    ----------
    ints : int64 array [n_atoms, 3]
        Initial counts, all below ``LIMIT`` in magnitude.
    quantum : float
        The power-of-two quantum.
    what : str
        'position' or 'momentum', for error messages.
    """

    def __init__(self, ints: np.ndarray, quantum: float, what: str):
        self.quantum = quantum
        self.what = what
        self._ints = [np.array(ints, dtype=np.int64)]
        self._ints += [np.empty_like(self._ints[0]) for _ in range(2)]
        self._floats = [decode(self._ints[0], quantum)]
        self._floats += [np.empty_like(self._floats[0]) for _ in range(2)]
        self._bounds = [float(np.abs(self._ints[0]).max(initial=0)), 0.0, 0.0]
        self._current = self._checkpoint = 0

    @property
    def ints(self) -> np.ndarray:
        """The current counts (int64); overwritten by later updates."""
        return self._ints[self._current]

    @property
    def floats(self) -> np.ndarray:
        """The current exact image in float64; overwritten by later updates."""
        return self._floats[self._current]

    def add_integers(self, r: np.ndarray):
        """Add the integer-valued float array ``r`` (not modified).

        ``r`` is float64 ``[n_atoms, 3]`` in quanta, already rounded.  Raises :class:`QuantumRangeError` and leaves the value unchanged if
        an element of ``r`` or of the sum is non-finite or out of range.
        """
        r_max = max(r.max(initial=0.0), -r.min(initial=0.0))
        if not r_max < LIMIT:  # also NaN
            _check_range(r, self.what + ' increment', self.quantum,
                         _STEP_ADVICE)
        spare = 3 - self._current - self._checkpoint if \
            self._current != self._checkpoint else (self._current + 1) % 3
        new = self._ints[spare]
        np.copyto(new, r, casting='unsafe')
        np.add(self._ints[self._current], new, out=new)
        # |counts| and |r| are below 2**53, so the int64 sum cannot wrap.
        # Float sums of whole numbers round monotonically, so the bound
        # never falls below LIMIT when the true sum could reach it.
        bound = self._bounds[self._current] + r_max
        if not bound < LIMIT:
            bound = max(new.max(initial=0), -new.min(initial=0))
            if not bound < LIMIT:
                _check_range(new, self.what, self.quantum, _STEP_ADVICE)
        self._bounds[spare] = float(bound)
        np.multiply(new, self.quantum, out=self._floats[spare])
        self._current = spare

    def checkpoint(self):
        """Remember the current value for :meth:`rollback`."""
        self._checkpoint = self._current

    def rollback(self):
        """Return to the value at the last :meth:`checkpoint`."""
        self._current = self._checkpoint


_STEP_ADVICE = ('The step was not taken. If the system is fine, construct the '
                'integrator with a larger quantum; if it is blowing up, use a '
                'smaller time step.')


def _check_range(a: np.ndarray, what: str, quantum: float, advice: str):
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
