"""Exact, reversible velocity Verlet inside LAMMPS, each rank on its own atoms.

The exact state is LAMMPS's own: positions ``x`` and velocities ``v`` in
the distributed per-atom arrays, kept on power-of-two grids so that every
float64 value is an exact image of an integer count.  Nothing is gathered:
atoms migrate between ranks, are sorted and wrap across periodic faces with
the arrays LAMMPS already moves, and those moves are exact on the grid.

One step of ``dt`` (a power of two, in LAMMPS time units), as LAMMPS runs it:

``initial_integrate`` (``fix move``, velocity variables)
    ``v += k``, then ``x += dt v``.  ``k``, the first half-kick, is a
    per-atom array (``fix property/atom``) left by the previous step.  The
    drift needs no rounding: ``dt v`` is a multiple of ``dt q_v``, itself a
    multiple of the position quantum, so the float sum is exact.
``post_force`` (``fix external``, a Python callback on every rank)
    ``k = q_v rint(dt/2 F/(m q_v))`` from this step's forces; ``v += k``
    (the second half-kick) and ``k`` is kept for the next step's first.

Running with ``-dt`` undoes a step bit for bit: the rounding is odd, so the
negated time step rounds every increment to its negative.

Forces are a pure function of the positions only up to history noise:
which rank computed a pair, and the order of the neighbour lists, set the
rounding of the sums.  Kicks are therefore *guarded* (one rule with the
ASE integrators, :mod:`ase_reversible.purity`): an increment within the
noise bound of a rounding boundary on any rank stops the run after that
step, the step's kick is taken back, and the forces are recomputed by a
LAMMPS setup, which re-sorts every rank's atoms into spatial bins holding
one atom each (a canonical order, a function of the positions alone) and
rebuilds every list from there.  Both branches give ``rint`` of the clean
increment.  A setup whose bins held two atoms, where it mattered, is
retried with bins half the size.
"""

from __future__ import annotations

import math
import os
import re
import tempfile
import warnings
from pathlib import Path

import numpy as np

from ..core.codec import LIMIT, check_quantum, guard_band_crossed, quantum_for
from ..core.codec import round_odd
from ..core.quanta import MIN_MOMENTUM_BITS, POSITION_ROOM
from ..errors import ImpureForcesError
from ..purity import NOISE_REFERENCE_EXTENT
from .mpi import World

#: The callback's verdicts, reduced by maximum over the ranks.
_AMBIGUOUS = 1     # an increment lay within the guard: take the step back
_NOT_CANONICAL = 2  # a setup's sort bins held two atoms where it mattered
_OUT_OF_RANGE = 4  # forces not finite, or kicks beyond the grid's range

#: Default bound on the history noise of a force component (LAMMPS force
#: units, for forces up to 1 and coordinates up to NOISE_REFERENCE_EXTENT,
#: scaled above as in the ASE integrators' guarded rounding).  Forces at
#: identical positions, a run's against a fresh start's and one rank's
#: against two ranks', differed by at most 1.1e-16 eV/Å for 864 argon
#: atoms under lj/cut and 1.3e-15 eV/Å for 500 copper atoms under eam
#: (max|F| 2 eV/Å); the clean recomputations of runs of 108,000 atoms saw
#: at most 1.6e-15.  This bound, scaled for those boxes, is 240 times the
#: largest.
FORCE_NOISE = 2.0**-44
#: Fraction of steps meant to need a clean recomputation: each costs a
#: LAMMPS setup, 2.4 to 5 steps' time (measured, 4,000 to 256,000 atoms).
CLEAN_RATE = 0.0025

#: Who may run the step (``ReversibleLammps(path=...)``).
PATHS = ('auto', 'compiled', 'python')

#: Unit styles whose force and distance scales the noise bound assumes
#: (forces of order 1, coordinates of order 10 to 1000).
SUPPORTED_UNITS = ('metal', 'real', 'lj')

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

#: Fix styles that only add to or set forces, or only observe: the
#: motion stays the exact integrator's.  Any other fix is refused before
#: a run (LAMMPS's all-capital styles are its own internal fixes).
PASSIVE_FIXES = frozenset('''
    addforce aveforce setforce gravity efield spring spring/self
    spring/couple spring/rg indent lineforce planeforce enforce2d
    wall/lj93 wall/lj126 wall/lj1043 wall/harmonic wall/morse
    wall/colloid wall/table wall/region external print ave/time
    ave/atom ave/chunk ave/histo ave/histo/weight ave/correlate vector
    store/state property/atom halt balance'''.split())

#: Why other fixes are refused, by style prefix: the first that matches.
_FIX_REASONS = (
    (('nvt', 'npt', 'nph', 'press/', 'deform', 'box/relax'),
     'changes velocities or the box by a thermostat or barostat, which '
     'depends on more than positions, so the motion could not be run back; '
     'exact runs keep the box, and their thermostat is reversible nvt '
     '(ReversibleLammpsNose) in place of fix nvt'),
    (('nve', 'rigid', 'shake', 'rattle', 'move', 'nvk', 'nvl'),
     'integrates or constrains the atoms itself: they would be moved twice '
     '(reversible nve is the integrator, and constraints are not exact here)'),
    (('langevin', 'temp/', 'viscous', 'momentum', 'gld', 'gle', 'heat',
      'ehex', 'dpd', 'ttm', 'bd/', 'brownian'),
     'changes velocities by friction, noise or rescaling, which depends on '
     'more than positions: the motion could not be run back'),
    (('deposit', 'pour', 'evaporate', 'gcmc', 'atom/swap', 'bond/',
      'widom'),
     'adds, removes or changes atoms or bonds during a run'),
    (('wall/reflect', 'recenter', 'dt/reset'),
     'sets positions, velocities or the time step itself during a run'),
)

#: Pair styles whose forces depend on velocities or on history, by prefix.
_HISTORY_PAIRS = ('dpd', 'gran', 'lubricate', 'brownian', 'sdpd', 'mdpd',
                  'edpd', 'tdpd')

#: Long-range solvers whose force noise was measured (PPPM: rhodopsin,
#: 32,000 atoms, forces at identical positions differed by at most
#: 2.1e-13 kcal/mol/Å with max|F| 133 on 1 and 2 ranks, 73 times below
#: the guard's bound; benchmarks/lammps_pppm_noise.py).
MEASURED_KSPACE = ('pppm',)

#: Default sort-bin width over the mean interatomic spacing (V/N)^(1/3).
#: Two atoms share a bin only if closer than 2 sqrt(3) times the width,
#: 0.87 (V/N)^(1/3): 0.77 of the nearest-neighbour distance of an fcc
#: crystal, closer than any pair comes in a liquid or solid at the
#: temperatures MD runs at.
SORT_BIN_SPACING = 0.25


class ReversibleLammps:
    """Exact reversible velocity Verlet on a running LAMMPS instance.

    Parameters
    ----------
    lmp : lammps.lammps
        An instance on every rank (``mpiexec -n R python ...``), with the
        atoms, masses and interactions defined, an orthogonal box (any
        boundaries, 2d or 3d), and no fix that integrates, thermostats,
        constrains or changes the box: this object defines its own
        integrator, and refuses those (ValueError naming the fix), here and
        before every run.  The time step is LAMMPS's ``timestep`` when a
        run starts; it must be a power of two (in magnitude) in LAMMPS time
        units, such as 0.001953125 ps (2^-9) in metal units.  A negative
        time step runs back.
    velocity_quantum : float, optional
        Velocity grid, LAMMPS velocity units; a power of two.  Default,
        chosen when the first run starts: the finest for which about
        ``CLEAN_RATE`` of steps need a clean recomputation, from the atom
        count, the lightest mass, the time step, ``force_noise`` and a
        force scale (``FORCE_SCALE`` of the unit style, or the largest
        force then if larger).  A restart from a LAMMPS restart or data
        file chooses the same grid unless its largest force is above both.
    force_noise : float
        Bound on the history noise of a force component, LAMMPS force
        units, for forces up to 1 and coordinates up to 32 (scaled by
        max|F| and the box's extent above), the rule of the ASE
        integrators' guarded rounding; default ``FORCE_NOISE``.
    sort_bin : float, optional
        Width of the spatial bins LAMMPS sorts atoms into at every setup,
        LAMMPS distance units.  Default ``SORT_BIN_SPACING`` times the mean
        interatomic spacing.
    name : str
        Prefix of the fixes and variables it defines.
    path : {'auto', 'compiled', 'python'}
        Who runs the step.  ``'compiled'``: ``fix reversible/nve``, a
        LAMMPS plugin built on first use (:mod:`.plugin`), at the cost of
        ``fix nve``.  ``'python'``: LAMMPS's ``fix move``, ``fix external``
        (a Python callback) and ``fix halt``, which need no compiler.
        ``'auto'`` (default): compiled where the plugin builds and loads on
        every rank, else Python, with one line in LAMMPS's output saying
        why.  Both paths take the same step to the bit, so a run may
        continue from one to the other.
    hint : callable, optional
        ``hint(option, value)``: how an error message names an option
        (the script runner's are its own ``reversible nve`` words).

    The fixes it defines are ``{name}_k`` (property/atom: the pending
    half-kick) and either ``{name}_nve`` (reversible/nve) or ``{name}_move``
    (move: the drift), ``{name}_ext`` (external: the kicks) and
    ``{name}_halt`` (halt: stops a run for a clean recomputation), at the
    start of every :meth:`run` and after every other fix: fixes that add to
    or set forces act before the kick.
    """

    #: The suffixes of the fixes it defines (``{name}_{suffix}``).
    _OWN_FIXES = ('k', 'nve', 'move', 'ext', 'halt', 'anchor')

    def __init__(self, lmp, *, velocity_quantum=None,
                 force_noise=FORCE_NOISE, sort_bin=None, name='rev',
                 path='auto', hint=None):
        self.lmp = lmp
        self.name = name
        self.world = World(lmp.extract_setting('world_size'))
        self.rank = lmp.extract_setting('world_rank')
        _checked_path(path)  # before anything is changed
        #: How an error message names an option: ``hint(name, value)``.
        #: The script runner sets it to its own ``reversible nve`` words.
        self.hint = hint or (lambda option, value: (
            f'construct ReversibleLammps with {option}={value!r}'))
        self.units = lmp.extract_global('units')
        self.dimension = lmp.extract_setting('dimension')
        self._check_system()
        self.force_noise = float(force_noise)
        if not (math.isfinite(self.force_noise) and self.force_noise > 0):
            raise ValueError(f'force_noise must be positive and finite, '
                             f'got {force_noise!r}')
        boxlo, boxhi = self._box()
        self.extent = float(max(np.abs(boxlo).max(), np.abs(boxhi).max(),
                                (boxhi - boxlo).max()))
        #: Position grid, LAMMPS distance units: room for POSITION_ROOM
        #: times the box's extent.
        self.position_quantum = quantum_for(POSITION_ROOM * self.extent)
        self._snap_box()  # first, so an anchor marked next is on it
        self.natoms = int(lmp.get_natoms())
        self._type_masses()
        #: Velocity grid, LAMMPS velocity units; if not given, chosen when
        #: the first run starts (or at the anchor, if the time step is a
        #: power of two by then), so the time step may be set afterwards.
        self.velocity_quantum = None
        if velocity_quantum is not None:
            self.velocity_quantum = check_quantum(velocity_quantum,
                                                  'velocity_quantum')
        #: The force scale the default grid was chosen for (None if the
        #: grid was given).
        self.force_scale = None
        #: Bits with which the grid resolves the rms velocity component
        #: when it is chosen (None for atoms at rest).
        self.velocity_bits = None
        self._grid_told = False
        if sort_bin is None:
            volume = float(np.prod(boxhi - boxlo))
            sort_bin = SORT_BIN_SPACING * (volume / self.natoms) ** (1 / 3)
        self.sort_bin = float(sort_bin)
        #: Steps whose kicks were taken back and recomputed from clean
        #: forces, and setups retried with finer sort bins.
        self.clean_recomputations = 0
        self.sort_retries = 0
        #: The step of the latest clean recomputation (None before any).
        self.last_recomputed_step = None
        #: Largest ``|F_run - F_clean|`` seen at a clean recomputation, and
        #: the bound the guard held it to (LAMMPS force units).
        self.max_observed_noise = 0.0
        self.noise_bound_at_max = 0.0
        #: Largest force component the kicks met in the latest run (LAMMPS
        #: force units).
        self.largest_force = 0.0
        self._run_force = 0.0
        #: Whether the anchor was kept before the grid was chosen: it is
        #: snapped with the atoms when the grid is.
        self._anchor_off_grid = False
        self._mode = 'start'
        self._flag = 0
        self._noisy = None
        self._anchor_defined = False
        self._buffers = None
        self._prepared = False
        self.path = path
        self._define_fixes()

    # -- the per-step callback ---------------------------------------------

    def _callback(self, caller, step, nlocal, tag, x, fext):
        """``post_force`` on every rank: round, guard and apply the kick."""
        if self._mode == 'halted':
            return
        np_ = self.lmp.numpy
        f = np_.extract_atom('f')[:nlocal]
        v = np_.extract_atom('v')[:nlocal]
        pending = np_.extract_atom(f'd2_{self.name}_k')[:nlocal]
        y, k = self._scratch(nlocal)
        np.multiply(f, self._scale(nlocal), out=y)
        round_odd(y, out=k)
        # NaN propagates through both: the range test below refuses it.
        r_max = max(float(k.max(initial=0.0)), -float(k.min(initial=0.0)))
        if self._type_scale is None:
            f_max = (r_max + 0.5) / self._scale_min
        else:  # the kicks' largest would overstate it by the mass ratio
            f_max = float(np.abs(f).max(initial=0.0))
        if f_max > self._run_force:
            self._run_force = f_max
        bound = (self.force_noise * self._extent_factor * max(1.0, f_max)
                 * self._scale_max)
        local = 0
        if not r_max < LIMIT / 4:  # also catches NaN
            local |= _OUT_OF_RANGE
        elif guard_band_crossed(y, k, bound):
            local |= _AMBIGUOUS
        setup = self._mode in ('start', 'redo')
        if setup and not self._sorted_canonically(x[:nlocal]):
            local |= _NOT_CANONICAL
        flag = int(self.world.max(local)[0])
        np.multiply(k, self.velocity_quantum, out=k)
        if flag & _OUT_OF_RANGE:
            self._halt(_OUT_OF_RANGE)
            return
        if setup:
            if flag & _AMBIGUOUS and flag & _NOT_CANONICAL:
                # The clean forces may depend on history after all: take
                # nothing, drift once with the velocities as they are,
                # and let run() undo that drift and retry finer.
                pending[:] = 0.0
                self._halt(_NOT_CANONICAL)
                return
            if self._mode == 'redo':
                self._compare_with_noisy(f, tag[:nlocal])
                v += k
            pending[:] = k
            self._mode = 'step'
            return
        v += k
        pending[:] = k
        if flag & _AMBIGUOUS:
            self._noisy = (np.array(tag[:nlocal]), f.copy(), bound)
            self._halt(_AMBIGUOUS)

    def _scratch(self, nlocal):
        """Two reused ``[nlocal, 3]`` float arrays: fresh ones every step
        cost more than the arithmetic on them."""
        if self._buffers is None or len(self._buffers[0]) < nlocal:
            size = int(nlocal * 1.2) + 16
            self._buffers = (np.empty((size, 3)), np.empty((size, 3)))
        return self._buffers[0][:nlocal], self._buffers[1][:nlocal]

    def _halt(self, flag):
        self._flag = flag
        self._mode = 'halted'
        self.lmp.fix_external_set_vector(f'{self.name}_ext', 1, float(flag))

    def _scale(self, nlocal):
        """Per-atom ``dt/2 ftm2v / (m q_v)`` as a column ``[n, 1]``, or a
        scalar when every type has the same mass."""
        if self._type_scale is None:
            return self._scalar_scale
        types = self.lmp.numpy.extract_atom('type')[:nlocal]
        return self._type_scale[types][:, None]

    def _sorted_canonically(self, x_nc):
        """Whether this rank's atoms sit one to a sort bin, in bin order,
        as LAMMPS's ``Atom::sort`` left them at this setup: then their
        order, and so every sum over them, is a function of positions."""
        lo = np.array(self.lmp.extract_global('sublo'), dtype=float)
        hi = np.array(self.lmp.extract_global('subhi'), dtype=float)
        n_bins = np.maximum(((hi - lo) * (1.0 / self.sort_bin)).astype(int),
                            1)
        index = ((x_nc - lo) * (n_bins / (hi - lo))).astype(np.int64)
        np.clip(index, 0, n_bins - 1, out=index)
        flat = (index[:, 2] * n_bins[1] + index[:, 1]) * n_bins[0] \
            + index[:, 0]
        return bool(np.all(np.diff(flat) > 0))

    def _compare_with_noisy(self, f_clean, tags):
        """Record how far the run's forces at the taken-back step were from
        the clean ones, for the atoms this rank held both times."""
        noisy_tags, f_noisy, bound = self._noisy
        order = np.argsort(noisy_tags)
        where = np.searchsorted(noisy_tags, tags, sorter=order)
        where = np.minimum(where, len(order) - 1)
        held = noisy_tags[order[where]] == tags
        noise = float(np.abs(f_clean[held] - f_noisy[order[where[held]]])
                      .max(initial=0.0))
        self._observed = (noise, bound / self._scale_max)

    # -- runs ----------------------------------------------------------------

    def run(self, nsteps: int):
        """Run ``nsteps`` exact steps of LAMMPS's current ``timestep``.

        Collective: every rank calls it.  LAMMPS's own output (thermo,
        dumps, restart files) works as in any run.  Raises
        :class:`ImpureForcesError` if a clean recomputation found the
        forces noisier than the guard's bound, and ValueError (before any
        step) for a time step that is not a power of two, or a fix, pair
        style or long-range solver exact runs cannot take.  Prints one
        line at its end: the steps, how many were recomputed from clean
        forces, and the largest force.
        """
        nsteps = int(nsteps)
        if nsteps < 0:
            raise ValueError(f'nsteps must be >= 0, got {nsteps}; to run '
                             'back, negate the timestep')
        self._prepare()
        first = self.step
        target = first + nsteps
        counts = self.clean_recomputations, self.sort_retries
        self._run_force = 0.0
        self._mode = 'start'
        self._attach()
        try:
            self._run_to(target)
        finally:
            self._detach()
            self._noisy = None
        clean = self.clean_recomputations - counts[0]
        retries = self.sort_retries - counts[1]
        self.largest_force = float(self.world.max(self._run_force)[0])
        rate = f' ({100 * clean / nsteps:.2g}%)' if nsteps else ''
        self._print(f'exact run of {nsteps} steps ({first} to {target}): '
                    f'{clean} recomputed from clean forces{rate}, '
                    f'{retries} sort retries, max|F| '
                    f'{self.largest_force:.3g}{self._summary()}')

    def _summary(self):
        """More for the line that ends a run (subclasses)."""
        return ''

    def _run_to(self, target):
        # A redo pending at the target (its last step was flagged) still
        # needs its setup: a run of 0 steps, or the kick taken back stays out.
        while self.step < target or self._mode == 'redo':
            segment_mode = self._mode
            self._begin_segment()
            before = self.step
            self.lmp.command(f'run {target - before}')
            self._end_segment()
            if self._flag == 0:
                break
            # A setup that stopped a run of 0 steps took no step to undo.
            stepped = self.step > before
            if self._flag & _AMBIGUOUS:
                # The kick just added is still the pending one: no step,
                # and so no migration or sort, came after it.
                self._take_back()
                self.clean_recomputations += 1
                self.last_recomputed_step = self.step
                self._mode = 'redo'
            elif self._flag & _NOT_CANONICAL:
                # A redo's setup keeps the forces it is to be compared with.
                retry = 'redo' if segment_mode == 'redo' else 'start'
                if stepped:
                    self._undo_drift()
                self.sort_retries += 1
                self.sort_bin /= 2
                self._set_sort()
                self._mode = retry
            else:
                if stepped:
                    self._undo_drift()
                raise self._halt_error()

    def _halt_error(self):
        """The error of a run halted by neither the guard nor the sort,
        raised once the atoms are back where the halted step began."""
        return FloatingPointError(
            f'forces at step {self.step + 1} are not finite or too large '
            f'for the velocity grid; the atoms are back at step '
            f'{self.step}, where this exact run can still be reversed. '
            'Check the potential and the time step.')

    def _take_back(self):
        """Take back the kick of a flagged step (the pending one: no step,
        and so no migration or sort, came after it)."""
        self._local('v')[...] -= self._local(f'd2_{self.name}_k')

    def _begin_segment(self):
        """Before each ``run`` of :meth:`_run_to`: no verdict yet, and the
        step told what its setup is (a start or a redo)."""
        self._flag = 0
        self._observed = None
        if self.path == 'compiled':
            self.lmp.command(f'fix_modify {self._fix_id()} mode {self._mode} '
                             f'sort_bin {self.sort_bin!r}')
        else:
            self.lmp.fix_external_set_vector(f'{self.name}_ext', 1, 0.0)

    def _end_segment(self):
        """After each ``run``: the verdict that stopped it (``_flag``), the
        largest force, and the clean recomputation's comparison, checked
        against the guard's bound."""
        if self.path == 'compiled':
            vector = [self._fix_vector(i) for i in range(5)]
            self._flag = int(vector[0])
            self._run_force = max(self._run_force, vector[1])
            observed = (vector[3], vector[4]) if vector[2] else None
        else:
            observed = None
            if self._observed is not None:  # every rank had the setup
                noise, bound = self._observed
                noise, inv_bound = self.world.max(noise, -bound)
                observed = (float(noise), float(-inv_bound))
        self._check_observed_noise(observed)

    def _fix_vector(self, index):
        return fix_vector(self.lmp, self._fix_id(), index)

    def _fix_id(self):
        """The ID of the compiled fix of the step."""
        return f'{self.name}_nve'

    def _local(self, name):
        """This rank's own atoms' rows of the per-atom array ``name``
        (a view: writing to it writes LAMMPS's array)."""
        nlocal = self.lmp.extract_setting('nlocal')
        return self.lmp.numpy.extract_atom(name)[:nlocal]

    @property
    def step(self) -> int:
        """LAMMPS's current step number."""
        return int(self.lmp.extract_global('ntimestep'))

    def _undo_drift(self):
        """Take back a step that stopped before its second half-kick: its
        drift, its first half-kick (zero after a failed setup) and its
        step number."""
        lmp = self.lmp
        v = self._local('v')
        self._local('x')[...] -= lmp.extract_global('dt') * v
        v -= self._local(f'd2_{self.name}_k')
        if self.path == 'compiled':  # not time-dependent: it may stay
            lmp.command(f'reset_timestep {self.step - 1}')
            return
        self._detach()
        lmp.command(f'reset_timestep {self.step - 1}')
        self._attach()

    def _check_observed_noise(self, observed):
        """``observed``: ``(noise, bound)`` over every rank at a clean
        recomputation of this segment, or None."""
        if observed is None:
            return
        noise, bound = observed
        if noise > self.max_observed_noise:
            self.max_observed_noise = float(noise)
            self.noise_bound_at_max = float(bound)
        if noise > bound:
            raise ImpureForcesError(
                f'forces at step {self.step} differed from their clean '
                f'recomputation by {noise:.3g}, more than the guard\'s bound '
                f'{bound:.3g} (LAMMPS force units): the forces depend on '
                'more than the positions, by more than the guard allows '
                '(LAMMPS\'s summation order, or a style whose noise was not '
                'measured), and earlier kicks may have been rounded from '
                'noisy forces. Run again from the start with a larger '
                'bound: '
                + self.hint('force_noise', _power_above(
                    self.force_noise * 8 * noise / bound)))

    # -- set-up ----------------------------------------------------------------

    def _prepare(self):
        """Everything a run needs that the user may have changed since the
        last: the time step, the masses, the box and the atoms' grid."""
        self._check_styles()
        self._set_sort()
        dt = self._timestep()
        self._snap_box()
        self._choose_grid(dt)
        self._check_drift_grid(dt)
        masses = self._type_masses()
        ftm2v = self.lmp.extract_global('ftm2v')
        per_type = 0.5 * dt * ftm2v / (masses * self.velocity_quantum)
        self._scale_max = float(np.abs(per_type).max())
        self._scale_min = float(np.abs(per_type).min())
        if np.all(per_type == per_type[0]):
            self._type_scale, self._scalar_scale = None, float(per_type[0])
        else:
            self._type_scale = np.concatenate([[np.nan], per_type])
        extent = max(self.extent, *np.abs(np.concatenate(self._box())))
        self._extent_factor = max(1.0, extent / NOISE_REFERENCE_EXTENT)
        self._prepared = True
        self._snap_atoms()
        if self._anchor_off_grid:
            anchor = self._anchor_views()[0]
            anchor[:, :3] = _snapped(anchor[:, :3], self.position_quantum)
            anchor[:, 3:] = self._snapped_velocities(anchor[:, 3:])
            self._anchor_off_grid = False
        # Lists built at every step they may be needed, never incomplete:
        # a list missing a pair forward may not miss it back.
        self.lmp.command('neigh_modify delay 0 every 1 check yes')

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
        self.force_scale = _power_above(max(FORCE_SCALE[self.units], f_max))
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
        snapped_lo, snapped_hi = _snapped(lo, q), _snapped(hi, q)
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
        for name, snap in (('x', lambda a: _snapped(a, q)),
                           ('v', self._snapped_velocities)):
            a = self.lmp.numpy.extract_atom(name)[:nlocal]
            snapped = snap(a)
            off = np.any(snapped != a, axis=1)
            change = float(np.abs(snapped - a).max(initial=0.0))
            a[:] = snapped
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
        return _snapped(v, self.velocity_quantum)

    def _define_fixes(self):
        n = self.name
        for command in (f'variable {n}_vx atom vx+d2_{n}_k[1]',
                        f'variable {n}_vy atom vy+d2_{n}_k[2]',
                        f'variable {n}_vz atom vz+d2_{n}_k[3]',
                        f'variable {n}_halt equal f_{n}_ext[1]'):
            self.lmp.command(command)
        self._set_sort()

    def _attach(self):
        """Define the fixes of a run, last, so that fixes which change
        forces run before the kick.  They exist only during run(): LAMMPS
        refuses a new timestep while a fix move exists, a run or
        minimisation outside run() must not call the kick, and restart
        and data files written between runs hold nothing of them (the
        pending half-kick is recomputed when a run starts)."""
        n = self.name
        if self.path == 'compiled':
            self.lmp.command(f'fix {n}_k all property/atom d2_{n}_k 3 '
                             'ghost no')
            self.lmp.command(f'fix {n}_nve all reversible/nve '
                             + self._compiled_arguments())
            return
        vz = f'v_{n}_vz' if self.dimension == 3 else 'NULL'  # z stays 0
        for command in (f'fix {n}_k all property/atom d2_{n}_k 3 ghost no',
                        f'fix {n}_move all move variable NULL NULL NULL '
                        f'v_{n}_vx v_{n}_vy {vz}',
                        f'fix {n}_ext all external pf/callback 1 1',
                        f'fix {n}_halt all halt 1 v_{n}_halt > 0.5 '
                        'error continue message no'):
            self.lmp.command(command)
        self.lmp.fix_external_set_vector_length(f'{n}_ext', 1)
        self.lmp.set_fix_external_callback(f'{n}_ext', self._callback, None)

    def _detach(self):
        fixes = (('nve', 'k') if self.path == 'compiled' else
                 ('halt', 'ext', 'move', 'k'))
        for fix in fixes:
            self.lmp.command(f'unfix {self.name}_{fix}')

    def _compiled_arguments(self):
        """``fix reversible/nve``'s words: the run's grid, guard and
        per-type scales, each float as its exact repr (the fix reads it
        back to the same bits).  Before the grid is chosen (the halted
        setup that measures the starting forces) they are placeholders."""
        ntypes = self.lmp.extract_global('ntypes')
        if self._prepared:
            scales = (self._type_scale[1:] if self._type_scale is not None
                      else [self._scalar_scale] * ntypes)
            words = {'velocity_quantum': self.velocity_quantum,
                     'force_noise': self.force_noise,
                     'extent_factor': self._extent_factor,
                     'sort_bin': self.sort_bin}
        else:
            scales = [0.0] * ntypes
            words = {'velocity_quantum': 1.0, 'force_noise': 0.0,
                     'extent_factor': 1.0, 'sort_bin': self.sort_bin}
        return ' '.join([f'kick {self.name}_k',
                         *(f'{key} {float(value)!r}'
                           for key, value in words.items()),
                         f'mode {self._mode}', 'scale',
                         *(repr(float(s)) for s in scales)])

    @property
    def path(self):
        """Who runs the step: ``'compiled'`` or ``'python'``.  Set it
        between runs, on every rank (collective), to continue on the other
        path; ``'auto'`` and ``'compiled'`` load the plugin first, as the
        constructor does."""
        return self._path

    @path.setter
    def path(self, wanted):
        self._path = self._choose_path(wanted)

    def _choose_path(self, wanted):
        """'compiled' if the plugin loads on every rank (and python was not
        asked for), else 'python'; raises where 'compiled' was asked for
        and cannot be had."""
        if _checked_path(wanted) == 'python':
            return 'python'
        reason = self._load_plugin_everywhere()
        if not reason:
            return 'compiled'
        if wanted == 'compiled':
            raise RuntimeError(f'the compiled exact step is not available: '
                               f'{reason}. To run on the Python path, '
                               + self.hint('path', 'python'))
        self._print(f'exact runs take the Python path (about 1.1-2x fix '
                    f'nve per step): {_quoted(reason)}')
        return 'python'

    def _load_plugin_everywhere(self):
        """Build and load the plugin on every rank: '' where it loaded on
        all of them, else why not.  Collective: every rank must take the
        same path, so one that failed sends all to Python."""
        from .plugin import PluginUnavailable, load
        reason = ''
        try:
            load(self.lmp)
        except PluginUnavailable as error:
            reason = str(error)
        if self.world.max(1.0 if reason else 0.0)[0] > 0:
            return reason or 'the plugin failed to load on another rank'
        return ''

    def _set_sort(self):
        # The compiled step sorts a setup's atoms itself, finely and then
        # into LAMMPS's own bins (fix_reversible_nve.cpp), which keeps the
        # pair loops' memory locality; the Python path leaves LAMMPS's
        # sort at the fine bins, at up to 4% of fix nve's time per step.
        if self.path == 'python':
            self.lmp.command(f'atom_modify sort 1000 {self.sort_bin!r}')

    def _check_system(self):
        lmp = self.lmp
        units = self.units
        if units not in SUPPORTED_UNITS:
            raise ValueError(
                f'units {units} are not supported: the force-noise bound '
                f'assumes the scales of {", ".join(SUPPORTED_UNITS)}')
        if lmp.extract_global('triclinic'):
            raise ValueError('the box is triclinic; exact runs need an '
                             'orthogonal box')
        if lmp.get_natoms() == 0:
            raise ValueError('there are no atoms: define them first')
        self._type_masses()
        self._check_styles()

    def _check_styles(self):
        """Refuse, before any step, every fix, pair style and long-range
        solver that would make the motion depend on more than positions,
        integrate the atoms a second time, or change the box, as LAMMPS's
        ``info`` lists them."""
        info = self._info('fixes system')
        ours = {f'{self.name}_{part}' for part in self._OWN_FIXES}
        for fix, style in re.findall(
                r'Fix\[\s*\d+\]:\s*(\S+),\s+style = (\S+),', info):
            if fix in ours or style in PASSIVE_FIXES or style.isupper():
                continue
            reason = next((why for prefixes, why in _FIX_REASONS
                           if style.startswith(prefixes)),
                          'is not known to leave the motion to the exact '
                          'integrator (only fixes that add to or set '
                          'forces, or that observe, are taken)')
            raise ValueError(
                f'fix {fix} ({style}) {reason}. Remove it (unfix {fix}) '
                'before the exact runs; for a thermostatted or constrained '
                'run, use LAMMPS\'s own integrators after reversible off')
        pair = re.search(r'Atoms\s*=.*style = (\S+)', info)
        if pair and pair.group(1).startswith(_HISTORY_PAIRS):
            raise ValueError(
                f'pair_style {pair.group(1)} computes forces from velocities '
                'or history, not from positions alone: its motion could not '
                'be run back. Exact runs need a conservative potential')
        kspace = re.search(r'Kspace style = (\S+)', info)
        if kspace and kspace.group(1) not in MEASURED_KSPACE + ('none',):
            raise ValueError(
                f'kspace_style {kspace.group(1)}: its force noise at '
                'identical positions was not measured, so the guard\'s bound '
                'may not cover it (measured: '
                f'{", ".join(MEASURED_KSPACE)}). Use kspace_style pppm')

    def _info(self, what):
        """LAMMPS's ``info`` about ``what``, as text, on every rank."""
        path = os.devnull
        if self.rank == 0:
            handle, path = tempfile.mkstemp(prefix='lammps-info-')
            os.close(handle)
        try:
            self.lmp.command(f'info {what} out overwrite "{path}"')
            text = Path(path).read_text() if self.rank == 0 else ''
        finally:
            if self.rank == 0:
                os.unlink(path)
        return self.world.share(text, self.rank)

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
                + self.hint('velocity_quantum', _power_above(
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
        # P(clean) per step ~ 2 * 3N * noise / q in units of the kick:
        # the rule of GuardedForces.min_momentum_quantum.
        ftm2v = self.lmp.extract_global('ftm2v')
        noise = (self.force_noise * self.force_scale
                 * max(1.0, self.extent / NOISE_REFERENCE_EXTENT))
        wanted = (2 * 3 * natoms * noise * 0.5 * dt * ftm2v / m_min
                  / CLEAN_RATE)
        # No finer than the drift allows: dt q_v a multiple of q_x.
        wanted = max(wanted, self.position_quantum / dt)
        return _power_above(wanted)

    def _print(self, text):
        """A line in LAMMPS's own output (screen and log), from rank 0."""
        self.lmp.command(f'print "{text}"')

    # -- the anchor: where a run back must land ---------------------------------

    def mark_anchor(self):
        """Keep every atom's exact state beside it, as a per-atom array that
        migrates with the atom: :meth:`compare_with_anchor` then needs no
        gather.  Collective."""
        if not self._anchor_defined:
            self.lmp.command(f'fix {self.name}_anchor all property/atom '
                             f'd2_{self.name}_anchor 6 ghost no')
            self._anchor_defined = True
        if self.velocity_quantum is None:
            try:
                dt = self._timestep()
            except ValueError:  # set later: the first run snaps the anchor
                dt = None
            if dt is not None:
                self._snap_box()
                self._choose_grid(dt)
        if self.velocity_quantum is not None:
            self._snap_atoms()
        self._anchor_off_grid = self.velocity_quantum is None
        anchor, x_u, v = self._anchor_views()
        anchor[:, :3] = x_u
        anchor[:, 3:] = v

    def compare_with_anchor(self):
        """``(atoms_off, largest_difference)`` over every rank: how many
        atoms' unwrapped positions or velocities differ from the anchor in
        any bit, and by how much at most.  Collective."""
        if not self._anchor_defined:
            raise RuntimeError('no anchor: call mark_anchor() first')
        anchor, x_u, v = self._anchor_views()
        off = np.any(anchor[:, :3] != x_u, axis=1) \
            | np.any(anchor[:, 3:] != v, axis=1)
        largest = max(float(np.abs(anchor[:, :3] - x_u).max(initial=0.0)),
                      float(np.abs(anchor[:, 3:] - v).max(initial=0.0)))
        count = self.world.sum(off.sum())[0]
        return int(count), float(self.world.max(largest)[0])

    def _anchor_views(self):
        lmp = self.lmp
        nlocal = lmp.extract_setting('nlocal')
        anchor = lmp.numpy.extract_atom(f'd2_{self.name}_anchor')[:nlocal]
        x = lmp.numpy.extract_atom('x')[:nlocal]
        v = lmp.numpy.extract_atom('v')[:nlocal]
        return anchor, x + self._images(nlocal) * self._period(), v

    def _images(self, nlocal):
        """Image flags ``[n, 3]`` unpacked from LAMMPS's packed integers."""
        lmp = self.lmp
        packed = np.asarray(lmp.numpy.extract_atom('image')[:nlocal],
                            dtype=np.int64)
        bits = lmp.extract_setting('IMGBITS')
        mask = lmp.extract_setting('IMGMASK')
        middle = lmp.extract_setting('IMGMAX')
        return np.stack([((packed >> (bits * axis)) & mask) - middle
                         for axis in range(3)], axis=1)

    def _period(self):
        lo, hi = self._box()
        return hi - lo

    # -- inspection ------------------------------------------------------------

    def gather(self):
        """``(ids, x, v)`` of every atom, ordered by id, on every rank:
        ``x`` unwrapped by the image flags (exact on the grid).  A
        collective copy of the whole system, for tests and small systems."""
        lmp = self.lmp
        n = int(lmp.get_natoms())
        ids = np.ctypeslib.as_array(lmp.gather_atoms('id', 0, 1)).copy()
        x = np.ctypeslib.as_array(lmp.gather_atoms('x', 1, 3)).reshape(n, 3)
        v = np.ctypeslib.as_array(lmp.gather_atoms('v', 1, 3)).reshape(n, 3)
        image = np.ctypeslib.as_array(
            lmp.gather_atoms('image', 0, 3)).reshape(n, 3)
        lo, hi = self._box()
        x = x + image * (hi - lo)
        order = np.argsort(ids)
        return ids[order], x[order], v[order].copy()

    def todict(self) -> dict:
        """The grid and guard settings, for logs and restarts."""
        return {'position_quantum': self.position_quantum,
                'velocity_quantum': self.velocity_quantum,
                'force_noise': self.force_noise, 'sort_bin': self.sort_bin}


def fix_vector(lmp, fix_id, index):
    """Element ``index`` of fix ``fix_id``'s global vector, on this rank."""
    from lammps import LMP_STYLE_GLOBAL, LMP_TYPE_VECTOR
    return float(lmp.extract_fix(fix_id, LMP_STYLE_GLOBAL, LMP_TYPE_VECTOR,
                                 index))


def _checked_path(path):
    """``path`` if it is one of PATHS, else ValueError."""
    if path not in PATHS:
        raise ValueError(f'path must be one of {", ".join(PATHS)}, got '
                         f'{path!r}')
    return path


def _snapped(values, quantum):
    """``values`` moved to the nearest multiples of ``quantum`` (a power of
    two: exact)."""
    return np.rint(values / quantum) * quantum


def _quoted(reason):
    """A reason as one line of LAMMPS's ``print``: no quotes, since print
    ends at a double quote and stops the script with "Unmatched single
    quote" at an apostrophe (LAMMPS 22 Jul 2025)."""
    return ' '.join(reason.replace('"', '`').replace("'", '`').split())


def _power_above(value):
    """The least power of two at or above ``value`` (> 0)."""
    return 2.0 ** math.ceil(math.log2(value))


__all__ = ['ReversibleLammps', 'FORCE_NOISE', 'CLEAN_RATE']
