"""ReversibleDynamics: the thin layer between ASE's MolecularDynamics and
the exact engine, shared by every reversible dynamics on atoms.

It keeps ASE's contract -- ``run``/``irun``, observers, loggers,
trajectories, ``dt``, ``get_time`` -- and the library's: every change made
around a run is taken exactly (the anchor of reversal moves, with an
:class:`~ase_reversible.AnchorMovedWarning`) or refused, the atoms always
show the exact state, and every frame carries the restart record.  A
subclass declares the dynamics: it builds ``self.system`` (the exact
variables and sub-steps over the atoms) and ``self.engine``.
"""

from __future__ import annotations

import warnings

import numpy as np
from ase import Atoms, units
from ase.md.md import MolecularDynamics

from ..adjoint import Cotangents, Gradients
from ..adjoint.cotangents import checked_gradient
from ..adjoint.products import checked_parameters, product_for, \
    zero_gradients
from ..adjoint.schedule import LossSchedule, checked_schedule
from ..core.codec import LIMIT, encode
from ..core.quanta import choose_grid
from ..core.record import (INFO_KEY, RecordWriter, read_record,
                           record_mismatch)
from ..errors import (AnchorMovedWarning, MachineChangedWarning,
                      NonFiniteStateError, QuantumRangeError)
from ..purity import calculator_members, discard_results, force_provider
from .checks import (check_calculator, check_energy_watch, check_steps,
                     check_timestep, checked_masses, fixed,
                     refuse_coarse_momentum_quantum)
from .constraints import constraint_projection
from .hamiltonian import Hamiltonian
from .machine import SECTION as MACHINE, compare, differences, explain, \
    frame_section, platform
from .state import FixedPointState
from .watch import (EQUAL_CALCULATOR, AnchorMoves, check_finite_cell,
                    non_finite, refuse_unholdable_values, same_values)




def projected_momenta(atoms, project):
    """The atoms' momenta ``[n_atoms, 3]`` projected onto the constraints."""
    p_nc = atoms.get_momenta()
    project(p_nc)
    return p_nc


def encoded(atoms, position_quantum, momentum_quantum, project):
    """The atoms' positions and projected momenta snapped to the grid, as
    int64 counts by variable name; under FixCom the momentum counts sum to
    zero (a net momentum removed in proportion to mass, as ASE does)."""
    counts = encode(projected_momenta(atoms, project), momentum_quantum,
                    'momentum')
    centre = getattr(project, 'centre', None)
    if centre is not None:
        counts = centre.balanced_counts(counts)
    return {'position': encode(atoms.positions, position_quantum, 'position'),
            'momentum': counts}


def admit(atoms, force_purity, force_noise):
    """What every reversible dynamics checks of the atoms it is
    constructed on, and chooses from them: ``(masses_n, project,
    purity)``, the masses ``[n_atoms]`` (amu), the constraint projection
    and the force provider.  Raises as the constructors do, before
    anything is changed; :func:`ase_reversible.check_calculator` runs it
    too, so that its verdict is the integrators'."""
    if not isinstance(atoms, Atoms):
        raise TypeError(
            f'The reversible integrators run ase.Atoms, got '
            f'{type(atoms).__name__}: filters that move the cell '
            '(UnitCellFilter, FrechetCellFilter, ...) are not supported; '
            'pass the Atoms themselves. To let the cell move at constant '
            'pressure, use ReversibleIsotropicNPT on the Atoms.')
    refuse_unholdable_values(atoms)
    check_calculator(atoms.calc, 'constructing the integrator')
    masses_n = checked_masses(atoms)
    project = constraint_projection(atoms)
    purity = force_provider(atoms, force_purity, force_noise)
    return masses_n, project, purity


def checked_grid(atoms, masses_n, project, purity, max_kick,
                 position_quantum=None, momentum_quantum=None, record=None):
    """The grid a dynamics runs the atoms on (the momentum quantum no finer
    than ``purity`` needs for kicks of up to ``max_kick`` ASE time units),
    refused (:class:`~ase_reversible.CoarseQuantumError`) if its momentum
    quantum would visibly change the momenta."""
    momenta = atoms.arrays.get('momenta', np.zeros((len(atoms), 3)))
    grid, origin = choose_grid(
        atoms.positions, atoms.cell, atoms.pbc, masses_n, momenta,
        position_quantum=position_quantum,
        momentum_quantum=momentum_quantum, record=record,
        momentum_floor=purity.min_momentum_quantum(
            len(atoms), max_kick,
            extent=float(np.abs(atoms.positions).max(initial=0.0))))
    refuse_coarse_momentum_quantum(
        masses_n, projected_momenta(atoms, project), grid, origin, purity)
    return grid


class ReversibleDynamics(MolecularDynamics):
    """Base of the reversible integrators; see
    :class:`ase_reversible.md.verlet.ReversibleVerlet`.

    A subclass's constructor checks its arguments, declares its system
    and engine and hands them to ``_attach`` before ASE's constructor
    runs, then calls ``_start`` with the watch of the atoms.
    """

    engine = None
    #: The running run's :class:`~.watch.AnchorMoves`, None between runs.
    _moves = None
    _forces_match_record = None
    #: Sections of the restart record a subclass writes and reads besides
    #: the quanta and the time (written by ``_record_sections``).
    record_sections = ()

    def _attach(self, system, engine, purity_choice, time0):
        """Take the declared system and engine (before ASE's constructor)."""
        self.system, self.engine = system, engine
        self._purity_choice = purity_choice  # (mode, force_noise)
        self._time0 = time0
        # Fixed for the integrator's life; the record needs them every step.
        self._write_record = RecordWriter(
            {name: v.quantum for name, v in engine.variables.items()})

    def _start(self, watch):
        """After ASE's constructor: watch the atoms, show the exact state,
        and check that a resumed frame's forces are those of its record."""
        self._watch = watch
        self.masses = self.system.m_n1
        self._show_anchor()
        self._forces_match_record = self._check_machine(
            getattr(self, '_resumed_machine', None))

    # -- time -------------------------------------------------------------

    @property
    def dt(self):
        """The time step, ASE time units; its sign is the direction of time.

        Setting it is honoured at the next step: a negated ``dt`` runs
        backwards exactly like :meth:`reverse`; a new size moves the anchor
        of reversal there (:class:`~ase_reversible.AnchorMovedWarning` if
        steps were taken since the anchor).
        """
        return self._dt if self.engine is None else self.engine.dt

    @dt.setter
    def dt(self, value):
        value = check_timestep(value)
        if self.engine is None:  # set by the base class's constructor
            self._dt = value
            return
        old = self.engine.dt
        taken = self.engine.set_dt(value)
        if (value > 0) != (old > 0) and self.engine.invariant is not None:
            # The way back may start outside the energy tolerance (a run
            # that ended between checks): the check waits until it is
            # inside again.
            self.engine.invariant.arm_for_retrace()
        if taken:
            old, new = abs(old), abs(value)
            self._anchor_moved(
                'the size of the time step changed',
                f'The time step changed from {old / units.fs:g} fs to '
                f'{new / units.fs:g} fs after {abs(taken)} steps. The new '
                'step is used from here; reversal with it leads back to '
                f'this point (time {self.get_time() / units.fs:.6g} fs), not '
                'beyond. To retrace the earlier steps exactly, set dt back '
                f'to {old / units.fs:g} fs (negated) here.', stacklevel=2)

    def reverse(self):
        """Flip the direction of time: further steps retrace the path.

        Negates :attr:`dt` (``dyn.dt = -dyn.dt`` does the same).
        ``run(n); reverse(); run(n)`` ends bit for bit where the first
        ``run`` started.  Returns the integrator, so
        ``dyn.reverse().run(n)`` works.
        """
        self.dt = -self.dt
        return self

    def get_time(self):
        """Simulated time in ASE time units, continued from a restart record.

        Goes back when the integrator runs backwards (unlike ``nsteps``,
        which counts every step taken).
        """
        return self._time0 + self.engine.elapsed()

    @property
    def step_index(self) -> int:
        """Signed steps taken with the present ``|dt|`` (back counts -1)."""
        return self.engine.step_index

    # -- the run ----------------------------------------------------------

    def irun(self, steps=50):
        """As ASE's ``irun`` (a generator yielding whether the run is done).

        Changes made around the run are taken (or refused) first, so even
        ``run(0)`` takes them.  The loop is this class's own, not ASE's:
        ASE's asks for forces after every step through a private hook
        whose existence depends on the ASE version; this one asks only
        where a step does not end with them already.
        """
        return self._loop(steps, alone=False)

    def run(self, steps=50):
        """Run ``steps`` steps; True once the run has reached them."""
        converged = steps == 0
        for converged in self._loop(steps, alone=True):
            pass
        return converged

    def _loop(self, steps, alone):
        """``irun``'s generator; ``alone``: the caller runs no code of its
        own between the steps (``run``)."""
        # A run that starts while another is open (an irun left unfinished,
        # a run inside an observer) takes over the collapsing: the other
        # warns each change from then on rather than losing any.
        moves = self._moves = AnchorMoves(type(self).__name__)
        try:
            self._sync()
            self.max_steps = self.nsteps + steps
            if self.nsteps == 0:
                self._ready()
                self.log()
                self.call_observers()
            yield self.nsteps == self.max_steps
            if alone and not self.observers and self._plain_hooks():
                yield from self._unwatched_steps()
                return
            while self.nsteps < self.max_steps:
                self.step()
                self.nsteps += 1
                self.log()
                self.call_observers()
                yield self.nsteps == self.max_steps
        finally:
            if self._moves is moves:
                self._moves = None
            moves.summarise(stacklevel=3 if alone else 2)

    def _plain_hooks(self):
        cls = type(self)
        return (cls.step is ReversibleDynamics.step
                and cls.log is MolecularDynamics.log
                and cls.call_observers is MolecularDynamics.call_observers)

    def _unwatched_steps(self):
        """The steps of a run that nothing outside sees until it ends: no
        observers, no caller between the steps, no hooks of a subclass.
        Nothing can change the atoms between these steps, so the checks
        for changes are left out, and nothing reads the momenta or the
        restart record (the energy check shows the momenta itself), so
        they are written once, when the run ends or fails.  Positions are
        shown by every drift: the force calls read them.
        """
        engine = self.engine
        try:
            while self.nsteps < self.max_steps:
                engine.step(self.nsteps)
                self.nsteps += 1
                yield self.nsteps == self.max_steps
        finally:
            self._committed()

    def _ready(self):
        """Before the first step: what ASE's loop would have computed."""

    def step(self):
        """One time step (called by ``run``/``irun``; ``dt`` may be negative).

        Takes any edit of the atoms first (:class:`AnchorMovedWarning`),
        checks the energy at checkpoint steps, then applies the sub-steps.
        If anything fails, the state is that before the step, bit for bit.
        """
        self._sync()
        self.engine.step(self.nsteps)
        self._committed()

    def _committed(self):
        self.system.show_momenta()
        self._write_frame_record()

    def _write_frame_record(self):
        """The restart record of the present state into ``atoms.info``: the
        subclass's sections and the platform with the digest of the forces
        the run holds here (:mod:`.machine`)."""
        sections = self._record_sections() or {}
        sections[MACHINE] = frame_section(self.system, self.atoms.calc,
                                          self.system.purity.mode)
        self._write_record(self.atoms.info, self.get_time(), sections)

    def _record_sections(self):
        """``{name: dict}`` for the sections in :attr:`record_sections`, or
        None: what a resumed run needs besides the quanta and the time."""
        return None

    # -- state and settings ----------------------------------------------

    @property
    def energy_check(self):
        """Steps between energy checks (0: off)."""
        return self.engine.invariant.interval

    @energy_check.setter
    def energy_check(self, value):
        self.engine.invariant.interval = check_energy_watch(value, None)[0]

    @property
    def energy_tolerance(self):
        """eV, as passed; None means the default described above."""
        return self.engine.invariant.tolerance

    @energy_tolerance.setter
    def energy_tolerance(self, value):
        self.engine.invariant.tolerance = check_energy_watch(0, value)[1]

    @property
    def anchor(self) -> FixedPointState:
        """A copy of the state reversal leads back to (int64 counts).

        The state right after the constructor, or right after the last
        change that was taken (:class:`AnchorMovedWarning`); same layout as
        :attr:`state`.
        """
        anchor = self.engine.anchor
        return FixedPointState(anchor['position'].copy(),
                               anchor['momentum'].copy())

    @property
    def state(self) -> FixedPointState:
        """A copy of the exact state: int64 positions and momenta in quanta.

        ``.ix_nc`` and ``.ip_nc``, int64 ``[n_atoms, 3]``; times
        ``grid.position_quantum`` (Å) and ``grid.momentum_quantum`` (amu Å
        / ASE time unit) they are exactly ``atoms.positions`` and
        ``atoms.get_momenta()``.
        """
        return FixedPointState(self.system.x.ints.copy(),
                               self.system.p.ints.copy())

    @property
    def counts(self) -> dict:
        """Copies of every exact variable's int64 counts, by name
        (``'position'``, ``'momentum'``, and a thermostat's own): the whole
        state reversal restores."""
        return self.engine.snapshot()

    @property
    def grid(self):
        """The two quanta (Å; amu Å / ASE time unit) and their ranges, a
        :class:`~ase_reversible.core.quanta.Grid` (fixed at construction)."""
        return self.system.grid

    @grid.setter
    def grid(self, value):
        fixed('grid (the quanta)')

    @property
    def force_purity(self):
        """The force provider in use (:mod:`ase_reversible.purity`).

        ``.mode`` is ``'sorted'``, ``'guarded'``, ``'cold-start'`` or
        ``'trust'``; a guarded provider also counts
        ``.clean_recomputations`` and keeps ``.max_observed_noise`` (eV/Å).
        """
        return self.system.purity

    def _grid_values(self, atoms):
        """``{name: float array or None}``: what the atoms show that an
        unedited frame holds on the grid of its record."""
        return {'position': atoms.positions,
                'momentum': atoms.arrays.get('momenta')}

    def _resumable_record(self, atoms):
        """The restart record in ``atoms.info`` if it fits the atoms."""
        record = read_record(atoms.info,
                             sections=(*self.record_sections, MACHINE))
        if record is None:
            return None
        mismatch = record_mismatch(record, self._grid_values(atoms))
        if mismatch is None:
            return record
        warnings.warn(
            f'The restart record in atoms.info does not fit these '
            f'atoms ({mismatch}); this is a new run: new quanta, '
            'time from 0. To resume a run exactly, start from an '
            'unedited trajectory frame; to silence this, remove the '
            f'record (atoms.info.pop({INFO_KEY!r})).',
            AnchorMovedWarning, stacklevel=4)
        return None

    @property
    def forces_match_record(self):
        """Whether the forces at the restart frame this integrator resumed
        are bitwise those of the run that wrote it (the digest in its
        record): True; False, after a
        :class:`~ase_reversible.MachineChangedWarning` (running back past
        the frame cannot be trusted to reach that run's earlier states);
        None if the integrator did not resume a frame, or its record has no
        digest or was written at other positions."""
        return self._forces_match_record

    def _check_machine(self, section):
        """Compare the forces at a resumed frame with the digest its record
        (``section``, the record's ``'machine'`` dict, or None) holds;
        warn if they differ, or if there is no digest and the platform
        differs.  Returns what :attr:`forces_match_record` reports."""
        if not isinstance(section, dict):
            return None
        same = compare(section, self.system)
        if same is None and 'positions' in section:
            return None  # written at other positions: not this frame's
        there, here = section.get('platform'), platform(self.atoms.calc)
        if same is None and not differences(there, here):
            return None
        if same:
            self._write_frame_record()  # with this machine's digest
            return True
        dropped = self.engine.anchor_index != self.engine.step_index
        if dropped:
            # The steps behind the frame ran under other forces: what was
            # kept to retrace them leads elsewhere here.
            self._install(self.engine.snapshot())
        else:
            self._write_frame_record()
        warnings.warn(explain(same is False, there, here,
                              self.get_time() / units.fs, dropped),
                      MachineChangedWarning, stacklevel=4)
        return False if same is False else None

    # -- the adjoint ------------------------------------------------------

    def backpropagate(self, steps, grad_positions=None, grad_momenta=None,
                      *, hvp='auto', parameters=(), carry=None, loss=None,
                      every=1, window=None):
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

        The retrace costs what the forward run cost, plus one product of
        the forces' Jacobian with a vector per step (kick-drift-kick,
        ``steps + 1`` in all; one per kick for drift-kick-drift): the
        calculator's ``vector_jacobian_product`` where it has one (one
        call gives the positions' and every parameter's part).  Observers
        are not called during it.

        A loss on many states of the run (a time average, say) is
        gathered in the same retrace by ``loss``: it is called at the
        sampled states as the retrace passes them and returns each one's
        own dL/dx, dL/dp.

        Parameters
        ----------
        steps : int
            Number of steps to retrace, >= 0.
        grad_positions : array_like ``[n_atoms, 3]``, optional
            dL/dx at the current state, (loss unit) / Å; None means zero.
        grad_momenta : array_like ``[n_atoms, 3]``, optional
            dL/dp at the current state, (loss unit) / (amu Å / ASE time);
            None means zero.
        hvp : {'auto', 'analytic', 'finite-difference'} or callable
            Where the products come from
            (:func:`ase_reversible.adjoint.product_for`): ``'auto'`` uses
            the calculator's ``vector_jacobian_product``, else its
            ``hessian_vector_product``, else a central finite difference
            of the forces (two force calls; positions only).  A callable
            ``hvp(atoms, v_nc)`` returns ``H v``.
        parameters : sequence of str
            Potential parameters (e.g. ``('epsilon', 'sigma')`` for
            :class:`ase_reversible.LennardJones`, or a network's weights
            for ``ase_reversible.torch.TorchCalculator``) whose
            gradients to accumulate; returned in ``.parameters``, each
            shaped like the parameter.
        carry : Gradients or False, optional
            What the previous segment's retrace returned, for a loss on
            several states split over several calls: its thermostat
            cotangents (``.thermostat``) go on from here.  Its positions
            and momenta are not used: pass them, plus this state's own
            gradients, as ``grad_positions`` and ``grad_momenta``.  A
            dynamics with thermostat variables
            (:class:`~ase_reversible.ReversibleNose`) refuses to go on from
            where its last retrace ended without it; ``False`` says that
            a new loss starts there.
        loss : callable, optional
            ``loss(atoms, k)``, called at the states ``k`` with ``k %
            every == 0``, ``k`` counted in steps from the state the
            retrace ends on (``k = steps`` is the present state, ``k = 0``
            the earliest); the atoms show that state's positions and
            momenta.  Returns None or ``(dL/dx, dL/dp)`` there (arrays
            ``[n_atoms, 3]``; either may be None).
        every : int
            Steps between the states ``loss`` is called at.
        window : int, optional
            Carry each state's gradient back at most this many steps (a
            truncated objective; at most ``every``, so that windows do not
            overlap).  Steps outside every window are undone with no
            product at all.  The gradients returned for the earliest
            state are those of the windows that reach it.

        Returns
        -------
        Gradients
            ``(grad_positions0, grad_momenta0)``, each ``[n_atoms, 3]``,
            with ``.parameters`` (dict) and ``.products``.  Constraints are
            honoured: the gradients are those of the constrained run, and
            the momentum gradient is projected (momenta a constraint holds
            are not free).

        If the retrace fails (the calculator raises, or an interrupt), the
        atoms are left at the last completed step, still exactly
        reversible, and the time step keeps its original sign.
        """
        steps = check_steps(steps)
        every, window = checked_schedule(loss, every, window)
        self._sync()
        available = self.engine.steps_since_anchor
        if steps > available:
            raise ValueError(
                f'Cannot retrace {steps} steps: only {available} were taken '
                'in this direction since the anchor of reversal (the '
                'constructor, or the last change taken: an edit of the '
                'atoms, the calculator, the constraints, the cell, or the '
                'size of dt). Steps before it ran under other dynamics. '
                f'Call backpropagate with at most {available} steps.')
        atoms, n = self.atoms, len(self.atoms)
        if carry not in (None, False) and not isinstance(carry, Gradients):
            raise TypeError('carry must be the Gradients the previous '
                            f'backpropagate returned (or False), got '
                            f'{type(carry).__name__}')
        if grad_positions is None and grad_momenta is None and loss is None:
            raise ValueError('Nothing to differentiate: give grad_positions '
                             'and/or grad_momenta (the loss\'s gradients at '
                             'the present state) or loss=.')
        ax_nc = checked_gradient(grad_positions, n, 'grad_positions')
        ap_nc = checked_gradient(grad_momenta, n, 'grad_momenta')
        names = checked_parameters(atoms.calc, parameters)
        cotangents = Cotangents(
            self._cotangents_of(ax_nc, ap_nc, carry),
            product=product_for(atoms.calc, hvp, names),
            grad_parameters=zero_gradients(atoms.calc, names))
        schedule = LossSchedule(steps, loss, every, window,
                                self.system.show_momenta,
                                self._loss_cotangents, atoms)
        schedule.start(cotangents, bool(ax_nc.any() or ap_nc.any()
                                        or carry))
        try:
            self.engine.retrace(steps, cotangents, visit=schedule)
        finally:
            self._committed()
        ax_nc, ap_nc, thermostat = self._gradients_of(cotangents)
        if self.system.centre is not None:
            self.system.centre.pull_back(ap_nc)
        self.system.project(ap_nc)
        grads = {name: float(g) if np.ndim(g) == 0 else g
                 for name, g in cotangents.grad_parameters.items()}
        return Gradients(ax_nc, ap_nc, grads, cotangents.products,
                         thermostat)

    def _cotangents_of(self, ax_nc, ap_nc, carry):
        """The cotangent of every exact variable, by name, for a loss
        with gradients ``ax_nc``, ``ap_nc`` on the shown positions and
        momenta, going on from ``carry`` (Gradients or None)."""
        return {'position': ax_nc, 'momentum': ap_nc}

    def _loss_cotangents(self, ax_nc, ap_nc):
        """What a loss with gradients ``ax_nc``, ``ap_nc`` (or None) on the
        shown positions and momenta of the present state adds to the
        exact variables' cotangents, by name."""
        added = {'position': ax_nc}
        if ap_nc is not None:
            added['momentum'] = ap_nc
        return added

    def _gradients_of(self, cotangents):
        """``(dL/dx, dL/dp, thermostat)`` on the shown positions and
        momenta (new arrays) and a thermostat's own variables (a dict),
        from the cotangents of the exact variables."""
        return (cotangents['position'].copy(),
                cotangents['momentum'].copy(), {})

    # -- changes made around the run --------------------------------------

    def _sync(self):
        """Take or refuse changes made around the run (see :mod:`.watch`)."""
        atoms = self.atoms
        changes = self._watch.changes(atoms)
        if changes and self._take_changes(changes):
            return
        momenta = atoms.arrays.get('momenta')
        if (same_values(atoms.arrays['positions'], self._shown_positions())
                and momenta is not None
                and same_values(momenta, self.system.shown_momenta())):
            return
        self._install(self._edited_counts(atoms, self.system.project))
        name = type(self).__name__
        self._anchor_moved(
            f'positions or momenta changed outside {name}',
            f'Positions or momenta were changed outside {name}. The change '
            'was taken and snapped to the grid; reversal now leads back to '
            'this point (time '
            f'{self.get_time() / units.fs:.6g} fs), not beyond.',
            stacklevel=3)

    def _shown_positions(self):
        """The positions the atoms show of the exact state, ``[n_atoms,
        3]`` (not to be modified)."""
        return self.system.x.floats

    def _anchor_moved(self, kind, message, stacklevel):
        """Warn that the anchor moved (:class:`AnchorMovedWarning`); within
        a run, a ``kind`` already warned is counted for the run's summary
        instead (:class:`~.watch.AnchorMoves`)."""
        if self._moves is None:
            warnings.warn(message, AnchorMovedWarning,
                          stacklevel=stacklevel + 1)
        else:
            self._moves.warn(kind, message, stacklevel + 1,
                             self.get_time() / units.fs)

    def _take_changes(self, changes):
        """Take a change of the dynamics, or refuse it leaving all as was.

        Everything that can refuse runs before anything is replaced.
        Returns True if the anchor moved (the state was re-installed),
        False for a calculator replaced by an equal one.
        """
        atoms = self.atoms
        if len(atoms) != len(self.system.x.ints):
            raise ValueError('The number of atoms changed; construct a new '
                             f'{type(self).__name__} for the new system (or put the '
                             'atoms back to continue this run).')
        if atoms.calc is None:
            raise RuntimeError('The atoms lost their calculator; attach one '
                               '(atoms.calc = ...) before running.')
        check_calculator(atoms.calc, 'running')
        check_finite_cell(atoms, 'Set it back (atoms.set_cell) to go on: '
                          'nothing was changed.')
        project = constraint_projection(atoms)
        masses_n = checked_masses(atoms)
        # Before the force provider is chosen: a probe would call the
        # calculator at these positions.
        counts = self._edited_counts(atoms, project)
        # Any change may alter how pure the forces are (a new calculator or
        # cut-off, atoms now near a periodic face): choose again.
        purity = force_provider(atoms, *self._purity_choice)
        if changes == [EQUAL_CALCULATOR]:
            self.system.purity = purity
            self._watch.take(atoms)
            self.system.kick.forget()
            return False
        # ASE's Calculator.set keeps results (and ASE's LennardJones its
        # neighbour list) from before the change: the first kick after it
        # would use them.  reset() is ASE's way to drop all of that.
        for calc in calculator_members(atoms.calc):
            if callable(getattr(calc, 'reset', None)):
                calc.reset()
            else:
                discard_results(calc)
        self.system.set_dynamics(masses_n, project, purity)
        self.masses = self.system.m_n1
        self._watch.take(atoms)
        self.engine.set_dt(self.engine.dt)  # coefficients use the masses
        self._install(counts)
        name, changed = type(self).__name__, ", ".join(changes)
        self._anchor_moved(
            f'{changed} changed outside {name}',
            f'Changed outside {name} since the last step: {changed}. The '
            'change was taken (positions and '
            'momenta snapped to the grid, momenta projected onto the '
            'constraints); reversal now leads back to this point (time '
            f'{self.get_time() / units.fs:.6g} fs), not beyond. To retrace '
            'further back exactly, undo the change when you get here.',
            stacklevel=4)
        return True

    def _change_setting(self, what, assign):
        """Take a new setting of the dynamics (``assign()`` makes it) from
        the next step on; the anchor moves here, with an
        :class:`AnchorMovedWarning` naming ``what`` if steps were taken."""
        self._sync()
        taken = self.engine.steps_since_anchor
        assign()
        self.engine.set_dt(self.engine.dt)  # prepare with the new setting
        self._install(self.engine.snapshot())
        if taken:
            changed = f'{what} of {type(self).__name__} changed'
            self._anchor_moved(
                f'the {changed}', f'The {changed} after {taken} steps; '
                'reversal now leads back to this point (time '
                f'{self.get_time() / units.fs:.6g} fs), not beyond.',
                stacklevel=3)

    def _edited_counts(self, atoms, project):
        """The counts of positions and momenta set on the atoms between
        runs, or, if the grid cannot hold them (NaN, infinite, out of
        range), the last exact state put back on the atoms and an error
        that says so: the values the edit replaced are gone, and without
        them neither the run nor its reversal could go on."""
        problem, error = non_finite(atoms), NonFiniteStateError
        advice = 'To change the state, set finite values.'
        if problem is None:
            error = QuantumRangeError
            advice = ('To change the state, set values within the range of '
                      'the grid (dyn.grid); a larger range needs a new '
                      'integrator with a larger position_quantum or '
                      'momentum_quantum.')
            # A virtual momentum (ReversibleNose) is not range-checked
            # when made: an out-of-range float casts to a count outside
            # (-LIMIT, LIMIT), refused below.
            with np.errstate(invalid='ignore'):
                try:
                    counts = self._encode(atoms, project)
                except QuantumRangeError as refused:
                    problem = 'the ' + str(refused).removesuffix(
                        ' Choose a larger quantum.')
                else:
                    problem = next(
                        (f'a {name} is outside the fixed-point range'
                         for name, c in counts.items()
                         if not ((c > -LIMIT) & (c < LIMIT)).all()), None)
            if problem is None:
                return counts
        self.system.show()
        raise error(
            f'Refused an edit made outside {type(self).__name__} since the '
            f'last step: {problem.rstrip(".")}. The fixed-point grid cannot '
            'hold it, and the values it replaced are gone, so the atoms were '
            'put back to the last exact state (positions and momenta at time '
            f'{self.get_time() / units.fs:.6g} fs): reverse() and further '
            'runs go on from there as if the edit had not been made. '
            + advice)

    def _encode(self, atoms, project):
        return encoded(atoms, self.system.x.quantum, self.system.p.quantum,
                       project)

    def _admit(self, atoms, force_purity, force_noise):
        """Check the atoms a dynamics is constructed on, and read what it
        needs from them: ``(masses_n, project, purity, record)``, the
        record None unless a restart record fits the atoms."""
        masses_n, project, purity = admit(atoms, force_purity, force_noise)
        record = self._resumable_record(atoms)
        # Compared with this machine's forces once the integrator stands.
        self._resumed_machine = record.get(MACHINE) if record else None
        return masses_n, project, purity, record

    def _hamiltonian(self, atoms, max_kick, position_quantum,
                     momentum_quantum, force_purity, force_noise,
                     system_class=Hamiltonian):
        """The atoms as a :class:`~.hamiltonian.Hamiltonian` on its grid,
        and the restart record it resumes (or None).

        Checks the atoms, chooses the force provider and the quanta (the
        momentum quantum no finer than the provider needs for kicks of up
        to ``max_kick`` ASE time units) and refuses a quantum that would
        visibly change the momenta, all before anything is changed.
        """
        masses_n, project, purity, record = self._admit(
            atoms, force_purity, force_noise)
        grid = checked_grid(atoms, masses_n, project, purity, max_kick,
                            position_quantum, momentum_quantum, record)
        counts = encoded(atoms, grid.position_quantum, grid.momentum_quantum,
                         project)
        return system_class(atoms, grid, counts, masses_n, project,
                            purity), record

    def _install(self, counts):
        """Make ``counts`` the anchor of reversal and show it on the atoms."""
        self.engine.install(counts)
        self._show_anchor()

    def _show_anchor(self):
        self.system.show()
        self._write_frame_record()


