"""ReversibleDynamics: the thin layer between ASE's MolecularDynamics and
the exact engine, shared by every reversible dynamics on atoms.

It keeps ASE's contract -- ``run``/``irun``, observers, loggers,
trajectories, ``dt``, ``get_time`` -- and the library's: every change made
around a run is taken exactly (the anchor of reversal moves, with an
:class:`~ase_reversible.AnchorMovedWarning`) or refused, the atoms always
show the exact state, and every frame carries the restart record.  A
subclass declares the dynamics: it builds ``self.system`` (the exact
variables and sub-steps over the atoms) and ``self.engine``.

This module holds the run loop, the clock and the views of the state;
the other parts live in their own modules: what a constructor checks and
chooses (:mod:`.admission`), the change contract (:mod:`.changes`), the
restart record and the checks of a resumed frame (:mod:`.restart`) and the
retrace of ``backpropagate`` (:mod:`ase_reversible.adjoint.retrace`).
"""

from __future__ import annotations

import numpy as np
from ase import units
from ase.md.md import MolecularDynamics

from ..adjoint.retrace import retrace_gradients
from ..adjoint.schedule import checked_schedule
from ..core.record import RecordWriter, read_record
from ..errors import UnsupportedConstraintError
from .admission import admit, checked_grid, encoded
from .changes import ChangeContract
from .checks import check_energy_watch, check_steps, check_timestep, fixed
from .hamiltonian import Hamiltonian
from .rigid.adjoint import shown_cotangents
from .rigid.layout import refuse_guarded_rigid, rigid_layout
from .rigid.system import SECTION as RIGID, VARIABLES as RIGID_VARIABLES
from .rigid.system import resumed_system, rigid_system
from .machine import SECTION as MACHINE
from .restart import RestartRecord
from .state import FixedPointState
from .watch import AnchorMoves, SystemWatch


class ReversibleDynamics(ChangeContract, RestartRecord, MolecularDynamics):
    """Base of the reversible integrators; see
    :class:`ase_reversible.md.verlet.ReversibleVerlet`.

    A subclass's constructor checks its arguments, declares its system
    and engine and hands them to ``_attach`` before ASE's constructor
    runs, then calls ``_start`` with the watch of the atoms.
    """

    engine = None
    #: Whether the dynamics runs molecules that FixBondLengths or
    #: FixLinearTriatomic make rigid as rigid bodies
    #: (:mod:`ase_reversible.md.rigid`), and whether backpropagate retraces
    #: them.
    rigid_bodies = rigid_adjoint = False

    def _open(self, system, engine, record, purity_choice, timestep,
              **ase_arguments):
        """The end of every dynamics' constructor: take the declared
        ``system`` and ``engine``, run ASE's constructor with
        ``ase_arguments`` (``trajectory``, ``logfile``, ...), then watch
        the atoms, show the exact state and check that a resumed frame's
        forces are those of its ``record``.  ``purity_choice``:
        ``(force_purity, force_noise)`` as the user passed them.

        Only the dynamics that wrote ``record`` (same class, same
        ``|timestep|``) goes on with its run: its clock and the check of
        the frame's forces.  Another keeps the record's quanta, which the
        system already holds, and starts its clock at 0, as a new ASE
        dynamics does."""
        self.system, self.engine = system, engine
        self._purity_choice = purity_choice
        self._warn_unfit_record(timestep)
        if not self._goes_on_with_record(timestep):
            record = self._resumed_machine = None
        # The clock goes on from the record's time, less the steps the
        # engine already counts (a buffered dynamics resumes its step).
        self._time0 = record['time'] - engine.elapsed() if record else 0.0
        # Fixed for the integrator's life; the record needs them every step.
        self._write_record = RecordWriter(
            {name: v.quantum for name, v in engine.variables.items()})
        # Before ASE's constructor: older ASE writes todict() into a
        # trajectory's header as soon as it is attached.
        MolecularDynamics.__init__(self, system.atoms, timestep,
                                   **ase_arguments)
        self._watch = SystemWatch(self.atoms)
        self.masses = self.system.atom_masses_n1
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
                self._refresh_properties()
                self.log()
                self.call_observers()
            yield self.nsteps == self.max_steps
            if alone and not self.observers and self._plain_hooks():
                yield from self._unwatched_steps()
                return
            while self.nsteps < self.max_steps:
                self.step()
                self.nsteps += 1
                self._refresh_properties()
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

    def _refresh_properties(self):
        """ASE's hook, called in ASE's order (before the first step and
        after each step the loop watches): the forces the logger and
        observers may read, where a step leaves them at hand.  A step
        that ends with a kick has computed them already (a cached
        lookup); one that ends with a drift does not need them, so none
        are computed for it (a logger or observer that reads them asks)."""
        if self.engine.plan[0][0] is self.system.kick:
            self.system.kick.forces()

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
            are not free).  With rigid molecules the gradients are on the
            exact variables: positions and momenta of the sites (the free
            atoms, then the bodies' centres of mass) ``[n_sites, 3]``, and
            ``.thermostat`` holds all four variables' by name
            (``'orientation'`` ``[n_bodies, 4]`` and ``'angular_momentum'``
            ``[n_bodies, 3]`` too), which ``carry=`` takes on.

        If the retrace fails (the calculator raises, or an interrupt), the
        atoms are left at the last completed step, still exactly
        reversible, and the time step keeps its original sign.
        """
        steps = check_steps(steps)
        if self.system.layout is not None and not self.rigid_adjoint:
            raise UnsupportedConstraintError(
                f'backpropagate does not run through rigid molecules under '
                f'{type(self).__name__} yet (ReversibleVerlet and '
                'ReversibleLangevin do). Nothing was changed.')
        every, window = checked_schedule(loss, every, window)
        self._sync()
        return retrace_gradients(
            self.engine, self.system, self.atoms, steps, grad_positions,
            grad_momenta, hvp=hvp, parameters=parameters, carry=carry,
            loss=loss, every=every, window=window,
            cotangents_of=self._cotangents_of,
            loss_cotangents=self._loss_cotangents,
            gradients_of=self._gradients_of, committed=self._committed)

    def _cotangents_of(self, ax_nc, ap_nc, carry):
        """The cotangent of every exact variable, by name, for a loss
        with gradients ``ax_nc``, ``ap_nc`` on the shown positions and
        momenta, going on from ``carry`` (Gradients or None)."""
        if self.system.layout is not None:
            # The atoms show a function of the bodies' variables: a
            # segment's gradients go on through them (``carry``).
            cotangents = shown_cotangents(self.system, ax_nc, ap_nc)
            for name, value in self._carried(carry, 'rigid bodies').items():
                cotangents[name] += value
            return cotangents
        return {'position': ax_nc, 'momentum': ap_nc}

    def _loss_cotangents(self, ax_nc, ap_nc):
        """What a loss with gradients ``ax_nc``, ``ap_nc`` (or None) on the
        shown positions and momenta of the present state adds to the
        exact variables' cotangents, by name."""
        if self.system.layout is not None:
            return shown_cotangents(self.system, ax_nc, ap_nc)
        added = {'position': ax_nc}
        if ap_nc is not None:
            added['momentum'] = ap_nc
        return added

    def _gradients_of(self, cotangents):
        """``(dL/dx, dL/dp, own)`` on the shown positions and momenta
        (new arrays) and a thermostat's own variables (a dict), from the
        cotangents of the exact variables.  With rigid bodies, on the
        sites (the free atoms, then the bodies' centres), and ``own``
        holds every variable's (the body variables' by name)."""
        if self.system.layout is not None:
            self._retrace_end = self._retrace_key()
            own = {name: np.array(value) for name, value in cotangents.items()}
            return own['position'].copy(), own['momentum'].copy(), own
        return (cotangents['position'].copy(),
                cotangents['momentum'].copy(), {})

    #: The exact variables' labels where the last backpropagate ended (a
    #: dynamics whose own variables carry gradient from one segment to the
    #: next sets it in :meth:`_gradients_of`).
    _retrace_end = None

    def _retrace_key(self):
        return tuple(v.label for v in self.system.variables.values())

    def _carried(self, carry, carrier):
        """The gradients on ``carrier``'s own variables (``'thermostat'``,
        ``'barostat'``) that ``carry`` (Gradients, False or None) goes on
        with, as a dict; refused where the state and ``carry`` disagree."""
        here = self._retrace_key()
        if carry is None and here == self._retrace_end:
            raise ValueError(
                'The atoms are where the last backpropagate ended. To go on '
                'with a loss on several states, pass what it returned as '
                f'carry= (the {carrier} carries part of the gradient from '
                'one segment to the next); to start a new loss here, pass '
                'carry=False.')
        if carry and here != self._retrace_end:
            raise ValueError(
                'carry= goes on from where the last backpropagate ended, '
                'but the state has changed since: pass carry=False or none.')
        return carry.thermostat if carry else {}

    # -- construction -----------------------------------------------------

    def _admit(self, atoms, force_purity, force_noise):
        """Check the atoms a dynamics is constructed on, and read what it
        needs from them: ``(masses_n, project, purity, record)``, the
        record None unless a restart record fits the atoms."""
        masses_n, project, purity = admit(atoms, force_purity, force_noise,
                                          rigid=self.rigid_bodies)
        self._read_writer(atoms.info)
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
        layout = rigid_layout(atoms, masses_n) if self.rigid_bodies else None
        if layout is not None:
            return self._rigid_system(atoms, layout, masses_n, purity,
                                      position_quantum, momentum_quantum)
        self._warn_rigid_record_unused(atoms.info)
        grid = checked_grid(atoms, masses_n, project, purity, max_kick,
                            position_quantum, momentum_quantum, record)
        counts = encoded(atoms, grid.position_quantum, grid.momentum_quantum,
                         project)
        return system_class(atoms, grid, counts, masses_n, project,
                            purity), record

    def _rigid_system(self, atoms, layout, masses_n, purity,
                      position_quantum, momentum_quantum):
        """The atoms with the rigid bodies of ``layout`` as a
        :class:`~.rigid.system.RigidSystem`, and the restart record it
        resumes (or None): the record's section holds the bodies' counts,
        which the atoms do not show, and a frame resumes where the atoms
        are those counts' image bit for bit."""
        refuse_guarded_rigid(purity, atoms.calc)
        record = read_record(atoms.info, names=RIGID_VARIABLES,
                             sections=(*self.record_sections, RIGID, MACHINE))
        system = None if record is None else resumed_system(
            atoms, layout, masses_n, purity, record)
        if system is None or (position_quantum or momentum_quantum):
            # No record, or an edited frame: a new start, as elsewhere.
            self._resumed_machine = None
            return rigid_system(atoms, layout, masses_n, purity,
                                position_quantum, momentum_quantum), None
        self._resumed_machine = record.get(MACHINE)
        return system, record

    def _install(self, counts):
        """Make ``counts`` the anchor of reversal and show it on the atoms."""
        self.engine.install(counts)
        self._show_anchor()

    def _show_anchor(self):
        self.system.show()
        self._write_frame_record()
