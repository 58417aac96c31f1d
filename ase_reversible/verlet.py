"""ReversibleVerlet: bit-for-bit reversible NVE dynamics for ASE."""

from __future__ import annotations

import itertools
import math
import warnings

import numpy as np
from ase import Atoms, units
from ase.md.md import MolecularDynamics

from . import fixedpoint as fp
from .adjoint import Adjoint
from .compositions import composition_for, substeps
from .constraints import constraint_projection
from .errors import (CoarseQuantumError, NonFiniteForcesError,
                     QuantumRangeError, UnstableIntegrationError)
from .io import INFO_KEY, read_record, write_record
from .purity import DEFAULT_FORCE_NOISE, discard_results, force_provider
from .watch import (EQUAL_CALCULATOR, SystemWatch, calculator_members,
                    same_values)

DRIFT, KICK = 'drift', 'kick'

#: Default steps between checks of the total energy.
ENERGY_CHECK_INTERVAL = 100
#: Temperature (K) whose kinetic energy is the smallest default tolerance.
ENERGY_TOLERANCE_TEMPERATURE = 100.0

#: Sub-steps of each scheme: (kind, fraction of the time step).  Both are
#: palindromes, so the same sequence run with -h is the exact inverse.
SCHEMES = {
    'velocity': ((KICK, 0.5), (DRIFT, 1.0), (KICK, 0.5)),
    'position': ((DRIFT, 0.5), (KICK, 1.0), (DRIFT, 0.5)),
}


class AnchorMovedWarning(UserWarning):
    """A change made around the run was taken: reversal starts anew there.

    Issued by :class:`ReversibleVerlet` at the next step (or
    ``backpropagate``) when the positions, momenta, masses, atomic
    numbers, cell, pbc, constraints, calculator or its parameters differ
    from what the integrator last saw, and when the size of ``dt`` changes
    after steps were taken.  The change is taken (positions and momenta
    snapped to the grid); reversal then leads back to that point
    (:attr:`ReversibleVerlet.anchor`), not beyond.  Also issued by the
    constructor when a restart record in ``atoms.info`` does not fit the
    atoms (new quanta are chosen).
    """


class ReversibleVerlet(MolecularDynamics):
    """Verlet dynamics in int64 fixed point that can be run back exactly.

    Positions and momenta are integers counted in power-of-two quanta
    (:mod:`ase_reversible.fixedpoint`).  Every sub-step adds the odd
    rounding of a function of the *other* variable -- drift:
    ``x += rint(c h p / m / q_x)``, kick: ``p += rint(c h F(x) / q_p)`` --
    so after ``run(n)``, :meth:`reverse` and ``run(n)`` the positions and
    momenta are bitwise those right after the constructor (J. Stam, "An
    Exact Bitwise Reversible Integrator", eq. posVerlet).

    The constructor snaps positions and momenta to the grid (a move of at
    most half a quantum) and writes them back to ``atoms``.  The values on
    ``atoms`` are exact images of the integers at every step, so any
    trajectory frame is an exact restart point: read it with
    ``ase.io.read``, attach a calculator and construct a new
    ``ReversibleVerlet``.

    Parameters
    ----------
    atoms : ase.Atoms
        With a calculator attached.
    timestep : float
        Time step in ASE time units (``5 * ase.units.fs``); may be
        negative to run backwards.
    trajectory, logfile, loginterval, append_trajectory
        As for :class:`ase.md.verlet.VelocityVerlet`.
    scheme : {'velocity', 'position'}
        ``'velocity'`` (default): kick-drift-kick.  ``'position'``:
        drift-kick-drift, the paper's position Verlet.  Both take one force
        evaluation per step; kick-drift-kick ends each step with the forces
        and energy at the new positions, so loggers, observers and
        trajectories read them for free, while drift-kick-drift has to
        compute them again whenever something asks.
    order : {2, 4, 6, 8, 10}
        Order of accuracy.  Above 2 a step is a symmetric composition of
        ``scheme`` steps (:mod:`ase_reversible.compositions`), still
        exactly reversible, costing one force call per stage: 5 for order
        4, 9 for 6, 15 for 8 and 33 for 10.
    composition : str or sequence of float, optional
        Another composition of the same order, such as ``'triple-jump'``
        (order 4 in 3 stages), or custom palindromic step fractions.
    position_quantum : float, optional
        Å, a power of two.  Default: from a restart record in
        ``atoms.info`` if present, otherwise 1024 times the system's size
        over 2**53 (:func:`~ase_reversible.fixedpoint.choose_position_quantum`).
    momentum_quantum : float, optional
        amu Å / ASE time unit, a power of two.  Default: from a restart
        record, otherwise 256 times the momentum scale over 2**53, raised
        if the force-purity mode needs it coarser.
    force_purity : {'auto', 'sorted', 'guarded', 'trust'}
        How forces are made a pure function of positions; see
        :mod:`ase_reversible.purity`.
    force_noise : float, optional
        Bound on history noise in the forces for ``'guarded'``, eV/Å.
    energy_check : int
        At steps 1, 2, 4, 8 and then every this many steps (default 100;
        0 turns the check off) the total energy is compared with its value
        where reversal is anchored; a difference above ``energy_tolerance`` stops the run
        with :class:`~ase_reversible.UnstableIntegrationError` before the
        next step, at a valid, reversible state (the check then stays
        quiet until the energy is back within the tolerance, so the run
        can be reversed).  This is what catches a time step past the
        stability limit.  A check reads the energy the
        calculator has from the last force call ('velocity'; for asap3 a
        fraction of a force call) or computes it ('position').
    energy_tolerance : float, optional
        eV.  Default: the kinetic energy at the anchor or that of the atoms
        at 100 K, whichever is larger.
    **kwargs
        Passed to :class:`ase.md.md.MolecularDynamics`, e.g.
        ``append_trajectory=True``.

    Attributes
    ----------
    dt : float
        The time step, ASE time units; its sign is the direction of time.
        Setting it is honoured at the next step: a negated ``dt`` runs
        backwards exactly like :meth:`reverse`; a new size moves the
        anchor of reversal there (:class:`AnchorMovedWarning` if steps
        were taken since the anchor).
    anchor : FixedPointState
        The state that reversal leads back to.
    grid : Grid
        The two quanta (Å; amu Å / ASE time unit) and their ranges.
    scheme : str
        ``'velocity'`` or ``'position'``.
    composition : Composition
        The composition in use: ``.name``, ``.order``, ``.stages`` (force
        calls per step) and ``.fractions``.
    energy_check : int
        Steps between energy checks (0: off).
    energy_tolerance : float or None
        eV, as passed; None means the default described above.

    Raises
    ------
    ValueError, TypeError
        Bad arguments (time step, scheme, order, quanta, masses, non-finite
        positions or momenta), before anything is changed or opened.
    RuntimeError
        The atoms have no calculator, or only the stored results of a
        trajectory frame (a SinglePointCalculator).
    CoarseQuantumError
        The momentum quantum (given, or raised by ``force_noise``) would
        visibly change the momenta.
    UnsupportedConstraintError
        A constraint other than FixAtoms, FixCartesian, FixedPlane and
        FixedLine.
    ImpureForcesError
        ``force_purity='auto'`` probed the calculator and its forces
        depended on its history.
    QuantumRangeError
        A position or momentum lies outside the range of the quanta given.
    """

    def __init__(self, atoms, timestep, trajectory=None, logfile=None,
                 loginterval=1, *, scheme='velocity', order=2,
                 composition=None, position_quantum=None,
                 momentum_quantum=None, force_purity='auto', force_noise=None,
                 energy_check=ENERGY_CHECK_INTERVAL, energy_tolerance=None,
                 **kwargs):
        # Validate everything before the base class touches any file.
        timestep = _check_timestep(timestep)
        if scheme not in SCHEMES:
            raise ValueError(f'scheme must be one of {tuple(SCHEMES)}, '
                             f'got {scheme!r}')
        self.energy_check, self.energy_tolerance = _check_energy_watch(
            energy_check, energy_tolerance)
        self._composition = composition_for(order, composition)
        self._substeps = substeps(SCHEMES[scheme], self._composition)
        if not isinstance(atoms, Atoms):
            raise TypeError(
                f'ReversibleVerlet integrates ase.Atoms at a fixed cell, got '
                f'{type(atoms).__name__}: filters that move the cell '
                '(UnitCellFilter, FrechetCellFilter, ...) are not supported; '
                'pass the Atoms themselves.')
        _check_calculator(atoms.calc, 'constructing ReversibleVerlet')
        masses_n = _checked_masses(atoms)
        for name in ('positions', 'momenta'):
            values = atoms.arrays.get(name)
            if values is not None and not np.all(np.isfinite(values)):
                raise ValueError(f'The atoms have non-finite {name}.')
        self._project = constraint_projection(atoms)
        self._purity_mode = force_purity
        self._force_noise = force_noise
        self._purity = force_provider(atoms, force_purity, force_noise)
        self._scheme = scheme
        grid, time0, origin = self._choose_grid(
            atoms, masses_n, timestep, position_quantum, momentum_quantum)
        self._grid = grid
        # Refusals end here, before the base class opens any file.
        self._check_momentum_quantum(atoms, masses_n, origin)
        state = _encode(atoms, grid, self._project)
        self._time0 = time0
        self._elapsed = []  # ASE time units taken with each earlier |dt|
        self._step_index = self._anchor_index = 0
        #: Signed steps taken with each earlier |dt|, so that the clock
        #: returns exactly to where it was when the steps are undone.
        self._steps_by_size = {}
        super().__init__(atoms, timestep, trajectory=trajectory,
                         logfile=logfile, loginterval=loginterval, **kwargs)
        self._m_n1 = masses_n[:, None]
        self._watch = SystemWatch(atoms)
        self._versions = itertools.count()
        self._install(state)
        self._prepare_plan()

    # -- public ---------------------------------------------------------

    def backpropagate(self, steps, grad_positions, grad_momenta=None, *,
                      hvp='auto', parameters=()):
        """Gradients of a loss with respect to the state ``steps`` steps ago.

        After ``run(steps)``, with ``grad_positions`` = dL/d(positions)
        and ``grad_momenta`` = dL/d(momenta) of a scalar loss L at the
        current state, retraces the ``steps`` steps exactly while
        integrating the adjoint (:mod:`ase_reversible.adjoint`), and
        returns dL/d(positions) and dL/d(momenta) at the state ``steps``
        steps earlier.  Afterwards the atoms are at that earlier state, bit
        for bit, and the time step has its original sign: ``run(steps)``
        repeats the forward run exactly.  Memory does not grow with
        ``steps``.

        The retrace costs what the forward run cost, plus one
        Hessian-vector product per step (kick-drift-kick, ``steps + 1`` in
        all; one per kick for drift-kick-drift).  Observers are not called during it.  A loss on
        several states of a run is handled by calling this once per
        segment, adding each state's own dL/dx, dL/dp to the gradients
        returned.

        Parameters
        ----------
        steps : int
            Number of steps to retrace, >= 0.
        grad_positions : array_like ``[n_atoms, 3]``
            dL/dx at the current state, (loss unit) / Å.
        grad_momenta : array_like ``[n_atoms, 3]``, optional
            dL/dp at the current state, (loss unit) / (amu Å / ASE time);
            None means zero.
        hvp : {'auto', 'analytic', 'finite-difference'} or callable
            How Hessian-vector products are computed
            (:func:`ase_reversible.hessian.hvp_for`): ``'auto'`` uses the
            calculator's ``hessian_vector_product`` if it has one, else a
            central finite difference of the forces (two force calls).
        parameters : sequence of str
            Potential parameters (e.g. ``('epsilon', 'sigma')`` for
            :class:`ase_reversible.LennardJones`) whose gradients to
            accumulate; returned in ``.parameters``.

        Returns
        -------
        Gradients
            ``(grad_positions0, grad_momenta0)``, each ``[n_atoms, 3]``,
            with ``.parameters`` (dict) and ``.hessian_vector_products``.
            Constraints are honoured: the gradients are those of the
            constrained run, and the momentum gradient is projected
            (momenta a constraint holds are not free).

        If the retrace fails (the calculator raises, or an interrupt), the
        atoms are left at the last completed step, still exactly
        reversible, and the time step keeps its original sign.
        """
        steps = _check_steps(steps)
        self._sync()
        available = (self._step_index - self._anchor_index) * self._direction
        if steps > available:
            raise ValueError(
                f'Cannot retrace {steps} steps: only {available} were taken '
                'in this direction since the anchor of reversal (the '
                'constructor, or the last change taken: an edit of the '
                'atoms, the calculator, the constraints, the cell, or the '
                'size of dt). Steps before it ran under other dynamics. '
                f'Call backpropagate with at most {available} steps.')
        adjoint = Adjoint(self.atoms, grad_positions, grad_momenta,
                          self._m_n1, self._project, hvp, parameters)
        self.reverse()
        try:
            # Each retrace sub-step undoes the forward sub-step of the same
            # kind and the opposite coefficient (the plans are palindromes).
            hooks = tuple(
                (lambda ch=-ch: adjoint.kick(ch)) if kind == KICK
                else (lambda ch=-ch: adjoint.drift(ch, self.atoms))
                for kind, ch in self._times)
            plan = tuple(
                step for hook, substep in zip(hooks, self._plan)
                for step in ((_call, hook), substep))
            for _ in range(steps):
                self._advance(plan)
            adjoint.flush(self.atoms)
        finally:
            self.reverse()
            self._energy_alarm = False
        return adjoint.result()

    def reverse(self):
        """Flip the direction of time: further steps retrace the path.

        Negates :attr:`dt` (``dyn.dt = -dyn.dt`` does the same).
        ``run(n); reverse(); run(n)`` ends bit for bit where the first
        ``run`` started.  Returns the integrator, so
        ``dyn.reverse().run(n)`` works.
        """
        self.dt = -self.dt
        return self

    @property
    def dt(self):
        """The time step, ASE time units; negative runs backwards."""
        return self._dt

    @dt.setter
    def dt(self, value):
        value = _check_timestep(value)
        old = self.__dict__.get('_dt')
        self._dt = value
        self._direction = 1 if value > 0 else -1
        if old is None:  # set by the base class's constructor
            return
        moved = None
        if abs(value) != abs(old):
            moved = self._change_step_size(abs(old), abs(value))
        if (value > 0) != (old > 0):
            # The way back may start outside the energy tolerance (a run
            # that ended between checks): the check waits until it is
            # inside again.
            self._energy_alarm = True
        self._prepare_plan()
        if moved:  # last: a warning made an error leaves all consistent
            warnings.warn(moved, AnchorMovedWarning, stacklevel=2)

    def _change_step_size(self, old, new):
        """Keep the clock exact and move the anchor to a new |dt|.

        Returns the warning to give if steps were taken since the anchor.
        """
        taken = self._step_index - self._anchor_index
        counts = self._steps_by_size
        counts[old] = counts.get(old, 0) + self._step_index
        self._step_index = self._anchor_index = counts.pop(new, 0)
        for h in [h for h, k in counts.items() if k == 0]:
            del counts[h]
        self._elapsed = [k * h for h, k in counts.items()]
        if not taken:
            return None
        self._anchor = self.state
        return (f'The time step changed from {old / units.fs:g} fs to '
                f'{new / units.fs:g} fs after {abs(taken)} steps. The new '
                'step is used from here; reversal with it leads back to '
                f'this point (time {self.get_time() / units.fs:.6g} fs), not '
                'beyond. To retrace the earlier steps exactly, set dt back '
                f'to {old / units.fs:g} fs (negated) here.')

    # Fixed at construction: an assignment would otherwise be ignored.
    @property
    def scheme(self):
        """``'velocity'`` or ``'position'`` (fixed at construction)."""
        return self._scheme

    @scheme.setter
    def scheme(self, value):
        _fixed('scheme')

    @property
    def composition(self):
        """The :class:`~ase_reversible.compositions.Composition` in use
        (fixed at construction)."""
        return self._composition

    @composition.setter
    def composition(self, value):
        _fixed('composition (and order)')

    @property
    def grid(self):
        """The two quanta, a :class:`Grid` (fixed at construction)."""
        return self._grid

    @grid.setter
    def grid(self, value):
        _fixed('grid (the quanta)')

    @property
    def anchor(self) -> fp.FixedPointState:
        """A copy of the state reversal leads back to (int64 counts).

        The state right after the constructor, or right after the last
        change that was taken (:class:`AnchorMovedWarning`); same layout as
        :attr:`state`.
        """
        return fp.FixedPointState(self._anchor.ix_nc.copy(),
                                  self._anchor.ip_nc.copy())

    @property
    def state(self) -> fp.FixedPointState:
        """A copy of the exact state: int64 positions and momenta in quanta.

        ``.ix_nc`` and ``.ip_nc``, int64 ``[n_atoms, 3]``; times
        ``grid.position_quantum`` (Å) and ``grid.momentum_quantum`` (amu Å
        / ASE time unit) they are exactly ``atoms.positions`` and
        ``atoms.get_momenta()``.
        """
        return fp.FixedPointState(self._x.ints.copy(), self._p.ints.copy())

    @property
    def force_purity(self):
        """The force provider in use (:mod:`ase_reversible.purity`).

        ``.mode`` is ``'sorted'``, ``'guarded'`` or ``'trust'``; a guarded
        provider also counts ``.clean_recomputations`` and keeps
        ``.max_observed_noise`` (eV/Å).
        """
        return self._purity

    def get_time(self):
        """Simulated time in ASE time units, continued from a restart record.

        Goes back when the integrator runs backwards (unlike ``nsteps``,
        which counts every step taken).
        """
        now = self._step_index * abs(self._dt)
        if self._elapsed:
            # One correctly rounded sum over every step size used: the same
            # multiset of steps gives the same time, whatever the order.
            now = math.fsum([*self._elapsed, now])
        return self._time0 + now

    def todict(self):
        """ASE's description of the dynamics (written into trajectory
        headers), plus ``scheme``, ``order``, ``composition``, the two
        quanta and the ``force_purity`` mode."""
        return {**super().todict(), 'scheme': self.scheme,
                'order': self.composition.order,
                'composition': self.composition.name,
                **self.grid.todict(), 'force_purity': self._purity.mode}

    def step(self):
        """One time step (called by ``run``/``irun``; ``dt`` may be negative).

        Takes any edit of the atoms first (:class:`AnchorMovedWarning`),
        checks the energy at checkpoint steps, then applies the sub-steps.
        If anything fails, the state is that before the step, bit for bit.
        """
        self._sync()
        if self.energy_check and _is_check_step(self.nsteps,
                                                self.energy_check):
            self._check_energy()
        self._advance(self._plan)

    def _advance(self, plan):
        """Apply the ``(substep, coefficient)`` pairs of ``plan`` as one step."""
        self._x.checkpoint()
        self._p.checkpoint()
        saved = self._x_version, self._f_cache
        try:
            for substep, coefficient in plan:
                substep(coefficient)
        except BaseException:
            # Updates never overwrite the checkpoint, so going back to it
            # undoes a partial step exactly.
            self._x.rollback()
            self._p.rollback()
            self._x_version, self._f_cache = saved
            self._r_key = None  # r_nc may hold a kick of the failed step
            self._write_positions()
            raise
        self._write_momenta()
        self._step_index += self._direction
        write_record(self.atoms, self.grid, self.get_time())

    def _check_energy(self):
        """Stop before a step if the energy drifted beyond the tolerance."""
        kinetic = self.atoms.get_kinetic_energy()
        energy = self.atoms.get_potential_energy() + kinetic
        if self._anchor_energy is None:
            self._anchor_energy = energy
            floor = 1.5 * len(self.atoms) * units.kB * \
                ENERGY_TOLERANCE_TEMPERATURE
            self._tolerance = (self.energy_tolerance
                               if self.energy_tolerance is not None
                               else max(kinetic, floor))
            return
        drift = energy - self._anchor_energy
        if abs(drift) <= self._tolerance:
            self._energy_alarm = False
            return
        # Raised once: the way back (reverse(), run) passes through the
        # same bad energies and must not be stopped.  The check is armed
        # again once the energy is back within the tolerance.
        if not self._energy_alarm:
            self._energy_alarm = True
            raise UnstableIntegrationError(
                f'The total energy has changed by {drift:.4g} eV since the '
                f'anchor of reversal (tolerance {self._tolerance:.4g} eV) '
                f'after step {self.nsteps}: the integration is unstable. Use '
                f'a smaller time step (now {abs(self.dt) / units.fs:g} fs). '
                'The step was not taken; the state is valid and reverse() '
                'leads back exactly (the check stays quiet until the energy '
                'is within the tolerance again). If the change is expected, '
                'raise energy_tolerance or pass energy_check=0.')

    # -- hooks of MolecularDynamics ------------------------------------

    def irun(self, *args, **kwargs):
        """As ASE's ``irun``; changes made around the run are taken (or
        refused) first, so even ``run(0)`` takes them."""
        self._sync()
        yield from super().irun(*args, **kwargs)

    def _refresh_properties(self):
        # ASE asks for forces after every step.  Kick-drift-kick ends each
        # step holding them; drift-kick-drift would pay a whole extra force
        # call, so its energies are computed only when a logger or observer
        # asks.  Only the call before the first step has work to do.
        if self.nsteps == 0:
            self._sync()
            if self._plan[0][0] == self._kick:
                self._forces()

    # -- sub-steps ------------------------------------------------------

    def _prepare_plan(self):
        qx, qp = self.grid.position_quantum, self.grid.momentum_quantum
        plan = []
        for kind, c in self._substeps:
            ch = c * self.dt  # negating dt negates every factor exactly
            if kind == DRIFT:
                # Applied to the momenta's exact float image p = ip * qp.
                plan.append((self._drift, ch / qx / self._m_n1))
            else:
                plan.append((self._kick, ch / qp))
        self._plan = tuple(plan)
        #: (kind, c h) of each sub-step, ASE time units.
        self._times = tuple((kind, c * self.dt) for kind, c in self._substeps)

    def _drift(self, factor_n1):
        y_nc = np.multiply(self._p.floats, factor_n1, out=self._y_nc)
        self._project(y_nc)
        np.rint(y_nc, out=y_nc)
        self._x.add_integers(y_nc)
        self._x_version = next(self._versions)
        self._write_positions()

    def _kick(self, scale):
        r_nc = self._r_nc
        key = (self._x_version, scale)
        # Kick-drift-kick ends a step and starts the next with the same kick
        # at the same positions: its rounding is reused, not recomputed.
        if self._r_key != key:
            self._r_key = None  # r_nc is about to be overwritten
            f_used_nc = self._purity.rounded_kick(
                self.atoms, self._forces(), scale, self._project, out=r_nc,
                scratch=self._y_nc)
            self._f_cache = (self._x_version, f_used_nc)
            self._r_key = key
        try:
            self._p.add_integers(r_nc)
        except QuantumRangeError:
            if not np.all(np.isfinite(self._f_cache[1])):
                raise NonFiniteForcesError(
                    f'{type(self.atoms.calc).__name__} returned non-finite '
                    'forces; the step was not taken and the state is still '
                    'reversible. Check the structure (overlapping atoms?) '
                    'and the calculator.') from None
            raise

    def _forces(self):
        """Forces at the current grid positions, computed once per position."""
        if self._f_cache is not None and self._f_cache[0] == self._x_version:
            return self._f_cache[1]
        f_nc = self._purity.forces(self.atoms)
        self._f_cache = (self._x_version, f_nc)
        return f_nc

    # -- state <-> atoms -------------------------------------------------

    def _choose_grid(self, atoms, masses_n, timestep, qx, qp):
        """The grid, the clock's start and where the momentum quantum came
        from (``'given'``, ``'record'``, ``'default'`` or ``'purity'``)."""
        record = read_record(atoms)
        time0 = 0.0
        origin = 'given' if qp is not None else 'default'

        if record is not None:
            mismatch = _record_mismatch(atoms, record)
            if mismatch is None:
                qx = record['position_quantum'] if qx is None else qx
                if qp is None:
                    qp, origin = record['momentum_quantum'], 'record'
                time0 = record['time']
            else:
                warnings.warn(
                    f'The restart record in atoms.info does not fit these '
                    f'atoms ({mismatch}); this is a new run: new quanta, '
                    'time from 0. To resume a run exactly, start from an '
                    'unedited trajectory frame; to silence this, remove the '
                    f'record (atoms.info.pop({INFO_KEY!r})).',
                    AnchorMovedWarning, stacklevel=3)
        if qx is None:
            qx = fp.choose_position_quantum(atoms.positions, atoms.cell,
                                            atoms.pbc)
        if qp is None:
            momenta = atoms.arrays.get('momenta', np.zeros((len(atoms), 3)))
            qp = fp.choose_momentum_quantum(masses_n, momenta)
            max_kick = abs(timestep) * max(
                abs(c) for kind, c in self._substeps if kind == KICK)
            floor = self._purity.min_momentum_quantum(
                len(atoms), max_kick,
                extent=float(np.abs(atoms.positions).max(initial=0.0)))
            if floor > qp:
                qp = math.ldexp(1.0, math.frexp(floor)[1])  # power of 2 > floor
                origin = 'purity'
        return fp.Grid(qx, qp), time0, origin

    def _check_momentum_quantum(self, atoms, masses_n, origin):
        """Refuse a momentum quantum that would visibly change the state."""
        p_nc = atoms.arrays.get('momenta', np.zeros((len(atoms), 3))).copy()
        self._project(p_nc)
        qp = self.grid.momentum_quantum
        problem = fp.momentum_resolution_problem(masses_n, p_nc, qp)
        if problem is None:
            return
        purity = self._purity
        source, remedy = {
            'given': ('as given', 'Pass a finer momentum_quantum, or none '
                      '(the default is chosen for these momenta).'),
            'record': ('from the restart record in atoms.info',
                       'Remove the record (atoms.info.pop('
                       f'{INFO_KEY!r})) to start a new run on a grid chosen '
                       'for these momenta.'),
            'default': ('chosen by default', 'Pass a finer '
                        'momentum_quantum.'),
            'purity': (f"raised to this by force_purity='{purity.mode}' with "
                       f'force_noise={purity.force_noise:.3g} eV/Å, which '
                       'keeps clean recomputations of the forces rare',
                       'force_noise bounds the history noise of the '
                       'forces; neighbour lists leave noise below 1e-12 '
                       'eV/Å (the default bound is '
                       f'{DEFAULT_FORCE_NOISE:.2g}). A '
                       'bound this large means the noise comes from state '
                       'the calculator carries between calls, such as a '
                       'self-consistent field: make each calculation start '
                       "from scratch and use force_purity='auto'. A "
                       'smaller force_noise or time step also gives a '
                       'finer quantum.'),
        }[origin]
        raise CoarseQuantumError(
            f'The momentum quantum {qp:.3g} amu Å / ASE time unit '
            f'({source}) is too coarse: {problem}. {remedy} Nothing was '
            'changed.')

    def _install(self, state):
        """Make ``state`` the anchor of reversal and show it on the atoms."""
        self._x = fp.FixedPointArray(state.ix_nc, self.grid.position_quantum,
                                     'position')
        self._p = fp.FixedPointArray(state.ip_nc, self.grid.momentum_quantum,
                                     'momentum')
        self._y_nc = np.empty(state.ix_nc.shape)
        self._r_nc = np.empty(state.ix_nc.shape)
        self._r_key = None
        self._x_version = next(self._versions)
        self._f_cache = None
        self._anchor = state
        self._anchor_index = self._step_index
        self._anchor_energy = None  # taken at the next check
        self._energy_alarm = False
        self._write_positions()
        self._write_momenta()
        write_record(self.atoms, self.grid, self.get_time())

    def _write_positions(self):
        self.atoms.arrays['positions'][:] = self._x.floats

    def _write_momenta(self):
        momenta = self.atoms.arrays.get('momenta')
        if momenta is None:
            self.atoms.set_momenta(self._p.floats, apply_constraint=False)
        else:
            momenta[:] = self._p.floats

    def _sync(self):
        """Take or refuse changes made around the run (see watch.py)."""
        atoms = self.atoms
        changes = self._watch.changes(atoms)
        if changes and self._take_changes(changes):
            return
        momenta = atoms.arrays.get('momenta')
        if (same_values(atoms.arrays['positions'], self._x.floats)
                and momenta is not None
                and same_values(momenta, self._p.floats)):
            return
        self._install(_encode(atoms, self.grid, self._project))
        warnings.warn(
            'Positions or momenta were changed outside ReversibleVerlet. The '
            'change was taken and snapped to the grid; reversal now leads '
            f'back to this point (time {self.get_time() / units.fs:.6g} fs), '
            'not beyond.', AnchorMovedWarning, stacklevel=3)

    def _take_changes(self, changes):
        """Take a change of the dynamics, or refuse it leaving all as was.

        Everything that can refuse runs before anything is replaced.
        Returns True if the anchor moved (the state was re-installed),
        False for a calculator replaced by an equal one.
        """
        atoms = self.atoms
        if len(atoms) != len(self._x.ints):
            raise ValueError('The number of atoms changed; construct a new '
                             'ReversibleVerlet for the new system (or put '
                             'the atoms back to continue this run).')
        if atoms.calc is None:
            raise RuntimeError('The atoms lost their calculator; attach one '
                               '(atoms.calc = ...) before running.')
        _check_calculator(atoms.calc, 'running')
        project = constraint_projection(atoms)
        masses_n = _checked_masses(atoms)
        # Any change may alter how pure the forces are (a new calculator or
        # cut-off, atoms now near a periodic face): choose again.
        purity = force_provider(atoms, self._purity_mode, self._force_noise)
        if changes == [EQUAL_CALCULATOR]:
            self._purity = purity
            self._watch.take(atoms)
            self._f_cache = self._r_key = None
            return False
        state = _encode(atoms, self.grid, project)
        # ASE's Calculator.set keeps results (and ASE's LennardJones its
        # neighbour list) from before the change: the first kick after it
        # would use them.  reset() is ASE's way to drop all of that.
        for calc in calculator_members(atoms.calc):
            if callable(getattr(calc, 'reset', None)):
                calc.reset()
            else:
                discard_results(calc)
        self._project, self._purity = project, purity
        self._m_n1 = self.masses = masses_n[:, None]
        self._watch.take(atoms)
        self._prepare_plan()
        self._install(state)
        warnings.warn(
            f'Changed outside ReversibleVerlet since the last step: '
            f'{", ".join(changes)}. The change was taken (positions and '
            'momenta snapped to the grid, momenta projected onto the '
            'constraints); reversal now leads back to this point (time '
            f'{self.get_time() / units.fs:.6g} fs), not beyond. To retrace '
            'further back exactly, undo the change when you get here.',
            AnchorMovedWarning, stacklevel=4)
        return True


def _encode(atoms, grid, project):
    """Snap the atoms' positions and (projected) momenta to the grid."""
    p_nc = atoms.get_momenta()
    project(p_nc)
    return fp.FixedPointState(
        fp.encode(atoms.positions, grid.position_quantum, 'position'),
        fp.encode(p_nc, grid.momentum_quantum, 'momentum'))


#: Steps (before the interval takes over) that catch an immediate blow-up.
EARLY_ENERGY_CHECKS = (1, 2, 4, 8)


def _is_check_step(n, interval):
    # The early checks catch a time step that blows up at once; after that
    # one energy per interval keeps the cost low (for asap3 EMT an energy
    # after the forces costs half a force call).
    return n % interval == 0 or n in EARLY_ENERGY_CHECKS


def _fixed(name):
    raise AttributeError(
        f'The {name} of a ReversibleVerlet is fixed when it is constructed; '
        'construct a new one (from the present atoms, which hold the exact '
        'state and its restart record) to change it.')


def _check_calculator(calc, doing):
    """Refuse a missing calculator or one that only holds stored results."""
    if calc is None:
        raise RuntimeError(f'The atoms have no calculator: attach one '
                           f'(atoms.calc = ...) before {doing}.')
    from ase.calculators.singlepoint import SinglePointCalculator
    if isinstance(calc, SinglePointCalculator):
        raise RuntimeError(
            'The atoms carry a SinglePointCalculator: the stored results of '
            'a trajectory frame, which cannot compute forces anywhere else. '
            f'Attach a real calculator (atoms.calc = ...) before {doing}; '
            "the frame's positions, momenta and restart record are kept.")


def _checked_masses(atoms):
    """The masses ``[n_atoms]`` (amu), refused unless positive and finite."""
    masses_n = atoms.get_masses()
    bad = ~(masses_n > 0) | ~np.isfinite(masses_n)
    if np.any(bad):
        atom = int(np.argwhere(bad)[0, 0])
        raise ValueError(f'Atom {atom} has mass {float(masses_n[atom])}: '
                         'every mass must be positive and finite (set it '
                         'with atoms.set_masses).')
    return masses_n


def _check_energy_watch(interval, tolerance):
    if isinstance(interval, bool) or not isinstance(interval, int) \
            or interval < 0:
        raise ValueError(f'energy_check must be a whole number of steps '
                         f'(0 turns the check off), got {interval!r}')
    if tolerance is not None:
        tolerance = float(tolerance)
        if not tolerance > 0:
            raise ValueError(f'energy_tolerance must be positive (eV), got '
                             f'{tolerance!r}')
    return interval, tolerance


def _call(hook):
    hook()


def _check_steps(steps):
    if isinstance(steps, bool) or not isinstance(steps, (int, np.integer)) \
            or steps < 0:
        raise ValueError(f'steps must be a whole number >= 0, got {steps!r}')
    return int(steps)


def _check_timestep(timestep):
    if isinstance(timestep, (str, bytes)):
        raise TypeError(f'timestep must be a number (ASE time units, e.g. '
                        f'5 * ase.units.fs), got the string {timestep!r}')
    try:
        dt = float(timestep)
    except (TypeError, ValueError):
        raise TypeError(f'timestep must be a number (ASE time units, e.g. '
                        f'5 * ase.units.fs), got {timestep!r}') from None
    if not math.isfinite(dt) or dt == 0:
        raise ValueError(f'timestep must be finite and non-zero (ASE time '
                         f'units, e.g. 5 * ase.units.fs), got {timestep!r}')
    return dt


def _record_mismatch(atoms, record):
    """Why the restart record cannot be resumed from, or None if it can."""
    try:
        grid = fp.Grid(record['position_quantum'], record['momentum_quantum'])
    except ValueError:
        return 'its quanta are not valid'
    momenta = atoms.arrays.get('momenta')
    if not (np.abs(atoms.positions).max(initial=0) < 0.5 * grid.position_range
            and (momenta is None or np.abs(momenta).max(initial=0)
                 < 0.5 * grid.momentum_range)):
        return 'the atoms lie outside its range'
    # A frame the integrator wrote holds whole numbers of quanta, exactly
    # (division by a power of two is exact).  Anything else -- a thermostat
    # run, new velocities, moved atoms -- was edited since it was written,
    # and its time would be wrong.
    if not (_on_grid(atoms.positions, grid.position_quantum)
            and (momenta is None
                 or _on_grid(momenta, grid.momentum_quantum))):
        return ('the positions or momenta are not on its grid: they were '
                'changed since the frame was written')
    return None


def _on_grid(values, quantum):
    counts = values / quantum
    return np.array_equal(np.rint(counts), counts)
