"""The choice of quanta: one function, :func:`choose_grid`.

Positions get a quantum that leaves ``POSITION_ROOM`` times the system's
size of range; momenta one that leaves ``MOMENTUM_ROOM`` times the momentum
scale.  The force-purity provider can only make the momentum quantum
coarser (a floor), and a quantum that would visibly change the momenta is
refused by :func:`momentum_resolution_problem`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from ase import units

from .codec import check_quantum, quantum_for, round_odd, value_range

#: Default head room of the position range over the system's extent.
POSITION_ROOM = 2.0**10
#: Default head room of the momentum range over the reference momentum.
MOMENTUM_ROOM = 2.0**8
#: Temperature (K) below which the momentum scale is not allowed to shrink.
MOMENTUM_TEMPERATURE_FLOOR = 1000.0
#: Fewest significant bits a momentum quantum must leave of the momentum
#: scale.  The default grid leaves about 44; a quantum with 12 resolves a
#: thermal momentum to 2.4e-4, and rounding errors of that size in every
#: kick swamp the integrator's own energy error.
MIN_MOMENTUM_BITS = 12
#: Largest relative change of the kinetic energy that snapping the momenta
#: to the grid may cause.  The default grid changes it by ~1e-13.
MAX_SNAP_KINETIC_CHANGE = 1e-6


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
        return value_range(self.position_quantum)

    @property
    def momentum_range(self) -> float:
        """Largest representable ``|momentum|`` (exclusive), ASE units."""
        return value_range(self.momentum_quantum)

    def todict(self) -> dict:
        """``{'position_quantum': ..., 'momentum_quantum': ...}`` (floats)."""
        return {'position_quantum': self.position_quantum,
                'momentum_quantum': self.momentum_quantum}


def choose_position_quantum(positions_nc, cell, pbc,
                            room: float = POSITION_ROOM) -> float:
    """Position quantum (Å) for a system, leaving ``room`` times its size.

    ``positions_nc`` is ``[n_atoms, 3]`` (Å), ``cell`` ``[3, 3]`` (Å), ``pbc``
    three booleans.  The size is the largest ``|coordinate|`` of the atoms or
    of the periodic cell vectors' span, and at least 1 Å.  With the default
    room of 1024 a 20 Å system gets a quantum of 2**-38 Å (3.6e-12 Å) and
    can spread to about 3e4 Å before an atom leaves the range.
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


def choose_angular_momentum_quantum(moments_bc, spins_bc,
                                    room: float = MOMENTUM_ROOM,
                                    temperature_floor: float =
                                    MOMENTUM_TEMPERATURE_FLOOR) -> float:
    """Quantum of rigid bodies' angular momenta (amu Å**2 / ASE time unit)
    leaving ``room`` times their scale: the largest ``|L|`` component of
    ``spins_bc`` ``[b, 3]``, or the thermal ``sqrt(I kB T)`` of the
    largest principal moment in ``moments_bc`` ``[b, 3]`` (amu Å**2) at
    ``temperature_floor`` K, whichever is larger -- the rule of
    :func:`choose_momentum_quantum`, with moments for masses."""
    return choose_momentum_quantum(np.asarray(moments_bc).reshape(-1),
                                   np.asarray(spins_bc).reshape(-1, 3),
                                   room, temperature_floor)


def choose_grid(positions_nc, cell, pbc, masses_n, momenta_nc, *,
                position_quantum=None, momentum_quantum=None, record=None,
                momentum_floor=0.0):
    """The grid of a run, and where its momentum quantum came from.

    Each quantum is, in this order of precedence: the one given, the one
    in the restart ``record`` (a dict with ``'position_quantum'`` and
    ``'momentum_quantum'``), or the default above.  A default momentum
    quantum below ``momentum_floor`` (amu Å / ASE time unit; what the
    force-purity provider needs) is raised to the next power of two
    above the floor.  Arrays as for the functions above.

    Returns
    -------
    (Grid, str)
        The grid and the origin of its momentum quantum: ``'given'``,
        ``'record'``, ``'default'`` or ``'purity'``.
    """
    qx, qp = position_quantum, momentum_quantum
    origin = 'given' if qp is not None else 'default'
    if record is not None:
        qx = record['position_quantum'] if qx is None else qx
        if qp is None:
            qp, origin = record['momentum_quantum'], 'record'
    if qx is None:
        qx = choose_position_quantum(positions_nc, cell, pbc)
    if qp is None:
        qp = choose_momentum_quantum(masses_n, momenta_nc)
        if momentum_floor > qp:
            qp = math.ldexp(1.0, math.frexp(momentum_floor)[1])
            origin = 'purity'
    return Grid(qx, qp), origin


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
    snapped_nc = round_odd(momenta_nc / quantum) * quantum
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
