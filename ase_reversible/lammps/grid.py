"""The exact grid of a LAMMPS run: the position grid from the box, the
default velocity grid from the guard's rule, and the box, atoms and time
step checked against them."""

from __future__ import annotations

import math
import warnings

import numpy as np

from ..core.codec import round_odd
from ..core.quanta import MIN_MOMENTUM_BITS
from ..purity.settings import guarded_momentum_quantum

#: Fraction of steps meant to need a clean recomputation: each costs a
#: LAMMPS setup, 2.4 to 5 steps' time (measured, 4,000 to 256,000 atoms).
CLEAN_RATE = 0.0025

#: Force scale (LAMMPS force units) the default velocity grid is chosen
#: for, per unit style: the guard's bound grows with the largest force on
#: a rank, so the grid must be coarser where forces are larger.  The grid
#: takes the larger of this and the largest force when it is chosen,
#: rounded up to a power of two (runs from a lattice start with no force
#: at all).  Largest forces measured in runs of LAMMPS's bench inputs and
#: examples: lj units 120 (in.lj), 296 (melt), 365 (in.chain), 581 (the 2d
#: min); metal 4.6 eV/Å (in.eam), 0.3 (argon); real 134 kcal/mol/Å
#: (in.rhodo without SHAKE).
FORCE_SCALE = {'lj': 256.0, 'metal': 4.0, 'real': 256.0}

#: The atom count whose default velocity grid every larger system keeps:
#: a larger system at the same density gets the same grid, and more of its
#: steps have a flagged kick.  The compiled fix recomputes those on the
#: rank that holds the atom (a few terms, not a setup), so the rate may
#: grow with the atom count; a grid that held the rate instead would drop
#: below 12 bits of the rms velocity near 3 x 10^5 atoms.
GRID_ATOMS = 100_000


class ExactGrid:
    """The grid of :class:`~.integrator.ReversibleLammps` (a part of it)."""

    def _choose_grid(self, dt):
        """The default velocity grid, once, for the time step of the first
        run and the forces where it starts."""
        if self.velocity_quantum is not None:
            if not self._grid_told:
                self._tell_grid()
            return
        # The forces where the run starts: a setup, as any run's, with the
        # run's fixes in place (LAMMPS would warn of no integrator) and
        # their kick off.
        self._mode = 'halted'
        self._attach()
        try:
            self.lmp.command('run 0 post no')
        finally:
            self._detach()
        nlocal = self.lmp.extract_setting('nlocal')
        f = self.lmp.numpy.extract_atom('f')[:nlocal]
        f_max = float(self.world.max(float(np.abs(f).max(initial=0.0)))[0])
        if not math.isfinite(f_max):
            raise FloatingPointError('the forces where the run starts are '
                                     'not finite: check the potential')
        self.force_scale = power_above(max(FORCE_SCALE[self.units], f_max))
        self.velocity_quantum = self._default_velocity_quantum(
            self.natoms, abs(dt), self._type_masses().min())
        self._tell_grid()

    def _tell_grid(self):
        self._grid_told = True
        scale = ('' if self.force_scale is None else
                 f' (for forces up to {self.force_scale!r})')
        self._print(f'exact grid: position_quantum {self.position_quantum!r}'
                    f', velocity_quantum {self.velocity_quantum!r}{scale}, '
                    f'force_noise {self.force_noise!r}, sort_bin '
                    f'{self.sort_bin!r}')
        self._check_resolution()

    def _snap_box(self):
        q = self.position_quantum
        lo, hi = self._box()
        snapped_lo, snapped_hi = snapped(lo, q), snapped(hi, q)
        if self.dimension == 2:  # z is 0 for every atom, and LAMMPS
            snapped_lo[2], snapped_hi[2] = lo[2], hi[2]  # keeps it so
        if np.array_equal(lo, snapped_lo) and np.array_equal(hi, snapped_hi):
            return
        words = ' '.join(f'{axis} final {float(a)!r} {float(b)!r}' for axis, a, b
                         in zip('xyz', snapped_lo, snapped_hi)
                         if self.dimension == 3 or axis != 'z')
        self.lmp.command(f'change_box all {words} units box')
        change = max(np.abs(snapped_lo - lo).max(),
                     np.abs(snapped_hi - hi).max())
        self._print(f'box snapped to the position grid {q!r} '
                    f'(moved by at most {change:.2g})')

    def _snap_atoms(self):
        nlocal = self.lmp.extract_setting('nlocal')
        moved = []
        q = self.position_quantum
        for name, snap in (('x', lambda a: snapped(a, q)),
                           ('v', self._snapped_velocities)):
            a = self.lmp.numpy.extract_atom(name)[:nlocal]
            on_grid = snap(a)
            off = np.any(on_grid != a, axis=1)
            change = float(np.abs(on_grid - a).max(initial=0.0))
            a[:] = on_grid
            moved += [off.sum(), change]
        counts = self.world.sum(moved[0], moved[2])
        changes = self.world.max(moved[1], moved[3])
        if counts.any():
            self._print(
                f'snapped to the exact grid: {int(counts[0])} positions (by '
                f'at most {changes[0]:.2g}), {int(counts[1])} velocities '
                f'(by at most {changes[1]:.2g}); runs back return here')

    def _snapped_velocities(self, v):
        """Velocities ``v`` as the nearest the exact state can show."""
        return snapped(v, self.velocity_quantum)

    def _box(self):
        lo, hi, *_ = self.lmp.extract_box()
        return np.array(lo, dtype=float), np.array(hi, dtype=float)

    def _timestep(self) -> float:
        dt = float(self.lmp.extract_global('dt'))
        if not (math.isfinite(dt) and dt != 0
                and math.frexp(abs(dt))[0] == 0.5):
            exponent = round(math.log2(abs(dt))) if dt else -9
            raise ValueError(
                f'timestep {dt!r} is not a power of two: the drift x += dt v '
                'is exact only then. Use, for example, timestep '
                f'{math.copysign(2.0 ** exponent, dt or 1)!r} (2^{exponent}) '
                'before this run')
        return dt

    def _check_drift_grid(self, dt):
        if self.velocity_quantum * abs(dt) < self.position_quantum:
            raise ValueError(
                f'timestep {dt!r} times the velocity quantum '
                f'{self.velocity_quantum!r} is finer than the position '
                f'quantum {self.position_quantum!r}: the drift would leave '
                'the grid. Use a larger timestep, or '
                + self.hint('velocity_quantum', power_above(
                    self.position_quantum / abs(dt))))

    def _check_resolution(self):
        """Warn when the velocity grid resolves the atoms' rms velocity
        component with fewer than MIN_MOMENTUM_BITS bits (the ASE
        integrators' limit): rounding errors of that size in every kick
        swamp the integrator's own energy error."""
        nlocal = self.lmp.extract_setting('nlocal')
        v = self.lmp.numpy.extract_atom('v')[:nlocal]
        total, count = self.world.sum(float(np.square(v).sum()), nlocal)
        if not total > 0:
            return
        bits = math.log2(math.sqrt(total / (3 * count))
                         / self.velocity_quantum)
        self.velocity_bits = bits
        if bits < MIN_MOMENTUM_BITS:
            text = (f'the velocity quantum {self.velocity_quantum!r} resolves '
                    f'the rms velocity with only {bits:.1f} bits (fewer than '
                    f'{MIN_MOMENTUM_BITS}): kicks lose precision. For '
                    f'{self.natoms} atoms the guard needs a grid this coarse '
                    'to keep clean recomputations rare; to trade speed for '
                    'precision, '
                    + self.hint('velocity_quantum',
                                self.velocity_quantum / 2**8))
            self._print(f'WARNING: {text}')
            warnings.warn(text, RuntimeWarning, stacklevel=3)

    def _type_masses(self) -> np.ndarray:
        if self.lmp.extract_setting('rmass_flag'):
            raise ValueError(
                'per-atom masses (rmass) are not supported: the atom_style '
                'gives every atom a mass of its own (sphere, ellipsoid, ...); '
                'use a style with per-type masses (atomic, bond, full, ...)')
        ntypes = self.lmp.extract_global('ntypes')
        masses = np.array(self.lmp.numpy.extract_atom('mass')[1:ntypes + 1],
                          dtype=float)
        if not np.all(masses > 0):
            raise ValueError('every atom type needs a positive mass')
        return masses

    def _default_velocity_quantum(self, natoms, dt, m_min):
        # The ASE integrators' rule at the force scale, for a kick of dt/2,
        # from LAMMPS's force x time to the lightest atom's velocity, for
        # at most GRID_ATOMS atoms in a box of this density.
        ftm2v = self.lmp.extract_global('ftm2v')
        counted = min(natoms, GRID_ATOMS)
        extent = self.extent * (counted / natoms) ** (1 / self.dimension)
        wanted = (guarded_momentum_quantum(
            counted, self.force_noise * self.force_scale, 0.5 * dt,
            extent, CLEAN_RATE) * ftm2v / m_min)
        # No finer than the drift allows: dt q_v a multiple of q_x.
        wanted = max(wanted, self.position_quantum / dt)
        return power_above(wanted)


def snapped(values, quantum):
    """``values`` moved to the nearest multiples of ``quantum`` (a power of
    two: exact), by the engine's one rounding rule."""
    return round_odd(values / quantum) * quantum


def power_above(value):
    """The least power of two at or above ``value`` (> 0)."""
    return 2.0 ** math.ceil(math.log2(value))
