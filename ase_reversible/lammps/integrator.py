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
noise bound of a rounding boundary is *flagged*, and its kick is taken
from a clean force instead.  The compiled fix recomputes a flagged atom's
force on the rank that owns it, summed from per-pair terms in the order of
the partners' atom IDs (``canonical_force.cpp``): a function of the
positions alone, the same on any number of ranks, so every kick is ``rint``
of the clean increment and a run takes the same bits on any decomposition.
Where the styles have no per-pair form (many-body pair styles, kspace,
angles), and on the Python path, a flag stops the run after that step
instead: the step's kick is taken back, and the forces are recomputed by
a LAMMPS setup, which re-sorts every rank's atoms into spatial bins
holding one atom each (a canonical order for that decomposition) and
rebuilds every list from there.  A setup whose bins held two atoms, where
it mattered, is retried with bins half the size.
"""

from __future__ import annotations

import math
import time

import numpy as np

from ..core.codec import check_quantum, quantum_for
from ..core.quanta import POSITION_ROOM
from ..errors import ImpureForcesError
from ..purity.settings import extent_factor
from .anchor import Anchor
from .fixes import StepFixes, StepPath
from .grid import ExactGrid, power_above, snapped
from .mpi import World
from .python_step import AMBIGUOUS, IMPURE, NOT_CANONICAL, PythonStep
from .styles import check_styles, check_units, lammps_info

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

#: Default sort-bin width over the mean interatomic spacing (V/N)^(1/3).
#: Two atoms share a bin only if closer than 2 sqrt(3) times the width,
#: 0.87 (V/N)^(1/3): 0.77 of the nearest-neighbour distance of an fcc
#: crystal, closer than any pair comes in a liquid or solid at the
#: temperatures MD runs at.
SORT_BIN_SPACING = 0.25


class ReversibleLammps(StepFixes, PythonStep, ExactGrid, Anchor):
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
        ``CLEAN_RATE`` of the steps of ``min(N, GRID_ATOMS)`` atoms at
        this density have a flagged kick, from the atom count, the
        lightest mass, the time step, ``force_noise`` and a force scale
        (``FORCE_SCALE`` of the unit style, or the largest force then if
        larger).  A restart from a LAMMPS restart or data
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
        Who runs the step (a string, or a
        :class:`~ase_reversible.lammps.fixes.StepPath`, equal to it).
        ``'compiled'``: ``fix reversible/nve``, a LAMMPS plugin built on
        first use (:mod:`.plugin`), at the cost of ``fix nve``.
        ``'python'``: LAMMPS's ``fix move``, ``fix external`` (a Python
        callback) and ``fix halt``, which need no compiler.
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
        StepPath.of(path)  # before anything is changed
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
        #: Steps whose kicks were recomputed from clean forces (locally, by
        #: the compiled fix, or by a global setup), and setups retried with
        #: finer sort bins.
        self.clean_recomputations = 0
        #: Atoms whose kicks the compiled fix recomputed on their own rank
        #: (over every rank), and the wall time of those recomputations
        #: (seconds, the slowest rank's, summed over runs).
        self.recomputed_atoms = 0
        self.recompute_seconds = 0.0
        #: Why flagged kicks are recomputed by a global setup ('' where
        #: the compiled fix recomputes them locally; None before a run).
        self.global_reason = None
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
        forces, and the largest force; for a run back (a negative
        timestep), also its rate (``rate_back`` below), as LAMMPS's own
        summary with its Performance line is left out.
        """
        nsteps = int(nsteps)
        if nsteps < 0:
            raise ValueError(f'nsteps must be >= 0, got {nsteps}; to run '
                             'back, negate the timestep')
        self._prepare()
        dt = float(self.lmp.extract_global('dt'))
        # LAMMPS's post-run summary computes its Performance line from the
        # signed timestep: a run back would print a negative ns/day.
        self._post = ' post no' if dt < 0 else ''
        started = time.perf_counter()
        first = self.step
        target = first + nsteps
        counts = (self.clean_recomputations, self.sort_retries,
                  self.recomputed_atoms)
        self._run_force = 0.0
        self._mode = 'start'
        self._attach()
        try:
            self._run_to(target)
        finally:
            self._detach()
            self._noisy = None
        seconds = time.perf_counter() - started
        clean = self.clean_recomputations - counts[0]
        retries = self.sort_retries - counts[1]
        atoms = self.recomputed_atoms - counts[2]
        self.largest_force = float(self.world.max(self._run_force)[0])
        where = ('' if self.global_reason
                 else f', {atoms} atoms on their own ranks')
        rate = (f' ({100 * clean / nsteps:.2g}%{where})' if nsteps
                else f' ({where[2:]})' if where else '')
        self._print(f'exact run of {nsteps} steps ({first} to {target}): '
                    f'{clean} recomputed from clean forces{rate}, '
                    f'{retries} sort retries, max|F| '
                    f'{self.largest_force:.3g}{self._summary()}'
                    + (rate_back(str(self.lmp.extract_global('units')), dt,
                                 nsteps, seconds) if self._post else ''))

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
            self.lmp.command(f'run {target - before}{self._post}')
            self._end_segment()
            if self._flag == 0:
                break
            if self._flag & IMPURE:
                # Taken, and not beyond the bound (else _end_segment
                # raised): a recomputed kick beyond the grid's range.
                raise FloatingPointError(
                    f'the clean force of a flagged atom at step {self.step} '
                    'is not finite or too large for the velocity grid. '
                    'Check the potential and the time step.')
            # A setup that stopped a run of 0 steps took no step to undo.
            stepped = self.step > before
            if self._flag & AMBIGUOUS:
                # The kick just added is still the pending one: no step,
                # and so no migration or sort, came after it.
                self._take_back()
                self.clean_recomputations += 1
                self.last_recomputed_step = self.step
                self._mode = 'redo'
            elif self._flag & NOT_CANONICAL:
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
        if self.path == StepPath.COMPILED:
            self.lmp.command(f'fix_modify {self._fix_id()} mode {self._mode} '
                             f'sort_bin {self.sort_bin!r}')
        else:
            self.lmp.fix_external_set_vector(f'{self.name}_ext', 1, 0.0)

    def _end_segment(self):
        """After each ``run``: the verdict that stopped it (``_flag``), the
        largest force, and the clean recomputation's comparison, checked
        against the guard's bound."""
        if self.path == StepPath.COMPILED:
            vector = [self._fix_vector(i) for i in range(5)]
            self._flag = int(vector[0])
            self._run_force = max(self._run_force, vector[1])
            observed = (vector[3], vector[4]) if vector[2] else None
            self.clean_recomputations += int(self._fix_vector(12))
            self.recomputed_atoms += int(self._fix_vector(13))
            self.recompute_seconds += self._fix_vector(15)
            self._tell_reason(GLOBAL_REASONS.get(int(self._fix_vector(14)),
                                                 'the styles of this run'))
        else:
            self._tell_reason('the Python path')
            observed = None
            if self._observed is not None:  # every rank had the setup
                noise, bound = self._observed
                noise, inv_bound = self.world.max(noise, -bound)
                observed = (float(noise), float(-inv_bound))
        self._check_observed_noise(observed)

    def _tell_reason(self, reason):
        """Say once, when kicks are not recomputed locally, what then
        holds across rank counts."""
        reason = reason or ''
        if reason and reason != self.global_reason:
            self._print(
                f'flagged kicks are recomputed by a global setup ({reason}): '
                'a run is the same bit for bit on any number of ranks only '
                'where no force component is flagged')
        self.global_reason = reason

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
        if self.path == StepPath.COMPILED:  # not time-dependent: may stay
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
                + self.hint('force_noise', power_above(
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
        # The guard's extent: the box's, or its faces' coordinates if
        # larger; the compiled fix takes the factor it gives.
        self._guard_extent = max(self.extent,
                                 *np.abs(np.concatenate(self._box())))
        self._extent_factor = extent_factor(self._guard_extent)
        self._prepared = True
        self._snap_atoms()
        if self._anchor_off_grid:
            anchor = self._anchor_views()[0]
            anchor[:, :3] = snapped(anchor[:, :3], self.position_quantum)
            anchor[:, 3:] = self._snapped_velocities(anchor[:, 3:])
            self._anchor_off_grid = False
        # Lists built at every step they may be needed, never incomplete:
        # a list missing a pair forward may not miss it back.
        self.lmp.command('neigh_modify delay 0 every 1 check yes')

    def _check_system(self):
        lmp = self.lmp
        check_units(self.units)
        if lmp.extract_global('triclinic'):
            raise ValueError('the box is triclinic; exact runs need an '
                             'orthogonal box')
        if lmp.get_natoms() == 0:
            raise ValueError('there are no atoms: define them first')
        self._type_masses()
        self._check_styles()

    def _check_styles(self):
        """Refuse the styles exact runs cannot take (:mod:`.styles`), as
        LAMMPS's ``info`` lists them now."""
        check_styles(
            lammps_info(self.lmp, self.world, self.rank, 'fixes system'),
            {f'{self.name}_{part}' for part in self._OWN_FIXES})

    def _print(self, text):
        """A line in LAMMPS's own output (screen and log), from rank 0."""
        self.lmp.command(f'print "{text}"')

    # -- inspection ------------------------------------------------------------

    def todict(self) -> dict:
        """The grid and guard settings, for logs and restarts."""
        return {'position_quantum': self.position_quantum,
                'velocity_quantum': self.velocity_quantum,
                'force_noise': self.force_noise, 'sort_bin': self.sort_bin}


#: Why the compiled fix cannot recompute flagged kicks on their own ranks,
#: by the code it reports (``CanonicalForce::Reason`` in
#: ``canonical_force.h``, which decides).
GLOBAL_REASONS = {
    0: '',
    1: 'no pair style',
    2: 'a kspace solver',
    3: 'a many-body pair style',
    4: 'a pair style without a per-pair function',
    5: 'angles, dihedrals or impropers',
    6: 'molecule templates',
    7: 'a fix that changes forces',
}


def fix_vector(lmp, fix_id, index):
    """Element ``index`` of fix ``fix_id``'s global vector, on this rank."""
    from lammps import LMP_STYLE_GLOBAL, LMP_TYPE_VECTOR
    return float(lmp.extract_fix(fix_id, LMP_STYLE_GLOBAL, LMP_TYPE_VECTOR,
                                 index))


__all__ = ['ReversibleLammps', 'FORCE_NOISE']


#: Simulated nanoseconds per LAMMPS time unit, by units style (``lj``: the
#: rate is in tau/day).
NS_PER_TIME_UNIT = {'metal': 1e-3, 'real': 1e-6}


def rate_back(units, dt, nsteps, seconds):
    """The end line's rate of a run back, ``'; back at R ns/day, S
    steps/s'``: ``|dt|`` (LAMMPS time units of style ``units``) times
    ``nsteps`` steps over the wall-clock ``seconds`` of the whole exact
    run, setups included (LAMMPS's Performance line counts its loop only,
    and with the signed timestep); '' for no steps or no time."""
    if nsteps <= 0 or not seconds > 0:
        return ''
    per_day = 86400.0 / seconds * nsteps * abs(dt)
    scale = NS_PER_TIME_UNIT.get(units)
    simulated = (f'{per_day:.4g} tau/day' if scale is None
                 else f'{per_day * scale:.4g} ns/day')
    return f'; back at {simulated}, {nsteps / seconds:.4g} steps/s'
