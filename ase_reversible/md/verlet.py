"""ReversibleVerlet: bit-for-bit reversible NVE dynamics for ASE.

The dynamics is declared, not hand-written: positions and momenta as exact
variables (:mod:`ase_reversible.md.hamiltonian`), a palindromic scheme of
drifts and kicks, and a composition; the engine
(:mod:`ase_reversible.core.engine`) runs it and the base class
(:mod:`ase_reversible.md.base`) keeps ASE's contract.
"""

from __future__ import annotations

from ..core.compositions import composition_for
from ..core.engine import Engine, InvariantCheck
from .base import ReversibleDynamics
from .checks import check_energy_watch, check_timestep, fixed
from .hamiltonian import explain_energy_drift, largest_kick

DRIFT, KICK = 'drift', 'kick'

#: Default steps between checks of the total energy.
ENERGY_CHECK_INTERVAL = 100

#: Sub-steps of each scheme: (kind, fraction of the time step).  Both are
#: palindromes, so the same sequence run with -h is the exact inverse.
SCHEMES = {
    'velocity': ((KICK, 0.5), (DRIFT, 1.0), (KICK, 0.5)),
    'position': ((DRIFT, 0.5), (KICK, 1.0), (DRIFT, 0.5)),
}


class ReversibleVerlet(ReversibleDynamics):
    """Verlet dynamics in int64 fixed point that can be run back exactly.

    Positions and momenta are integers counted in power-of-two quanta
    (:mod:`ase_reversible.core.codec`).  Every sub-step adds the odd
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
        With a calculator attached.  Its constraints are applied exactly
        (:mod:`ase_reversible.md.constraints`); under FixCom the total
        momentum is held at exactly zero (a net momentum is removed here,
        as ASE's FixCom does) and, with equal masses, the centre of mass
        exactly in place.
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
        ``scheme`` steps (:mod:`ase_reversible.core.compositions`), still
        exactly reversible, costing one force call per stage: 5 for order
        4, 9 for 6, 15 for 8 and 33 for 10.
    composition : str or sequence of float, optional
        Another composition of the same order, such as ``'triple-jump'``
        (order 4 in 3 stages), or custom palindromic step fractions.
    position_quantum : float, optional
        Å, a power of two.  Default: from a restart record in
        ``atoms.info`` if present, otherwise 1024 times the system's size
        over 2**53 (:func:`~ase_reversible.core.quanta.choose_position_quantum`).
    momentum_quantum : float, optional
        amu Å / ASE time unit, a power of two.  Default: from a restart
        record, otherwise 256 times the momentum scale over 2**53, raised
        if the force-purity mode needs it coarser.
    force_purity : {'auto', 'sorted', 'guarded', 'cold-start', 'trust'}
        How forces are made a pure function of positions; see
        :mod:`ase_reversible.purity`.
    force_noise : float, optional
        Bound on history noise in the forces for ``'guarded'``, eV/Å.
    energy_check : int
        At steps 1, 2, 4, ... (powers of two) and then every this many
        steps (default 100; 0 turns the check off) the total energy is
        compared with its value where reversal is anchored; a difference
        above ``energy_tolerance`` stops the run with
        :class:`~ase_reversible.UnstableIntegrationError` before the next
        step, at a valid, reversible state (the check then stays quiet
        until the energy is back within the tolerance, so the run can be
        reversed).  This is what catches a time step past the stability
        limit, within two steps of the energy crossing the tolerance:
        every second step the kinetic energy (no force call) is compared
        with its value at the last check, and a change by more than half
        the tolerance brings a check at once; a drift past half the
        tolerance brings the checks closer, down to every step.  A check
        reads the energy the calculator has from the last force call
        ('velocity'; for asap3 a fraction of a force call) or computes it
        ('position').
    energy_tolerance : float, optional
        eV.  Default: the kinetic energy at the anchor or that of the atoms
        at 100 K, whichever is larger.
    **kwargs
        Passed to :class:`ase.md.md.MolecularDynamics`, e.g.
        ``append_trajectory=True``.

    The time step, the anchor, the quanta and the settings are
    properties: ``dt``, ``anchor``, ``state``, ``energy_check``,
    ``energy_tolerance`` and ``force_purity`` (documented on
    :class:`~ase_reversible.md.base.ReversibleDynamics`), :attr:`~ase_reversible.md.base.ReversibleDynamics.grid`,
    :attr:`scheme` and :attr:`composition`.

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
        A constraint other than FixAtoms, FixCartesian, FixedPlane,
        FixedLine and FixCom, or FixCom with FixedPlane or FixedLine.
    ImpureForcesError
        ``force_purity='auto'`` probed the calculator and its forces
        depended on its history.
    QuantumRangeError
        A position or momentum lies outside the range of the quanta given.
    """

    rigid_bodies = rigid_adjoint = True

    def __init__(self, atoms, timestep, trajectory=None, logfile=None,
                 loginterval=1, *, scheme='velocity', order=2,
                 composition=None, position_quantum=None,
                 momentum_quantum=None, force_purity='auto', force_noise=None,
                 energy_check=ENERGY_CHECK_INTERVAL, energy_tolerance=None,
                 **kwargs):
        # Validate everything before the base class touches any file.
        timestep = check_timestep(timestep)
        if scheme not in SCHEMES:
            raise ValueError(f'scheme must be one of {tuple(SCHEMES)}, '
                             f'got {scheme!r}')
        energy_check, energy_tolerance = check_energy_watch(
            energy_check, energy_tolerance)
        composition = composition_for(order, composition)
        max_kick = largest_kick(SCHEMES[scheme], composition, timestep, KICK)
        # Refusals end here, before the base class opens any file.
        system, record = self._hamiltonian(
            atoms, max_kick, position_quantum, momentum_quantum,
            force_purity, force_noise)
        substep = {KICK: system.kick, DRIFT: system.drift}
        invariant = InvariantCheck(energy_check, energy_tolerance,
                                   system.energy, self._explain_drift,
                                   trigger=system.kinetic_energy)
        engine = Engine(system.variables,
                        tuple((substep[k], c) for k, c in SCHEMES[scheme]),
                        composition, timestep, invariant=invariant)
        self._scheme = scheme
        self._open(system, engine, record, (force_purity, force_noise),
                   timestep, trajectory=trajectory, logfile=logfile,
                   loginterval=loginterval, **kwargs)

    def _explain_drift(self, number, drift, tolerance):
        return explain_energy_drift(number, drift, tolerance, self.dt)

    # Fixed at construction: an assignment would otherwise be ignored.
    @property
    def scheme(self):
        """``'velocity'`` or ``'position'`` (fixed at construction)."""
        return self._scheme

    @scheme.setter
    def scheme(self, value):
        fixed('scheme')

    @property
    def composition(self):
        """The :class:`~ase_reversible.core.compositions.Composition` in use:
        ``.name``, ``.order``, ``.stages`` (force calls per step),
        ``.fractions`` (fixed at construction)."""
        return self.engine.composition

    @composition.setter
    def composition(self, value):
        fixed('composition (and order)')

    def todict(self):
        """ASE's description of the dynamics (written into trajectory
        headers), plus ``scheme``, ``order``, ``composition``, the two
        quanta and the ``force_purity`` mode."""
        return {**super().todict(), 'scheme': self.scheme,
                'order': self.composition.order,
                'composition': self.composition.name,
                **self.grid.todict(), 'force_purity': self.force_purity.mode}
