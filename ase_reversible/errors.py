"""Exceptions raised by ase-reversible.

Every error is raised *before* the offending update is committed: after
catching one, the integrator still holds a state that runs back exactly to
where reversal was last anchored.
"""


class ReversibilityError(Exception):
    """Base class of the errors specific to ase-reversible."""


class QuantumRangeError(ReversibilityError, OverflowError):
    """A position or momentum would leave the range of the fixed-point grid.

    Raised by a step (the step is not taken) or by the constructor (an
    input beyond the range of the quanta given).  An increment out of range
    usually means a blow-up (smaller time step); a value out of range, a
    system that outgrew its grid (coarser quantum).
    """


class NonFiniteForcesError(ReversibilityError, FloatingPointError):
    """The calculator returned NaN or infinite forces.

    Raised by a step, which is not taken (overlapping atoms, a calculator
    failure).
    """


class UnstableIntegrationError(ReversibilityError, RuntimeError):
    """The total energy drifted beyond its tolerance: the run is blowing up.

    Raised by the energy check before a step (``energy_check``,
    ``energy_tolerance`` of ReversibleVerlet); the usual cure is a smaller
    time step.
    """


class ImpureForcesError(ReversibilityError, RuntimeError):
    """The calculator's forces are not a pure function of the positions.

    Raised by the constructor when ``force_purity='auto'`` probes an
    unknown calculator (:func:`~ase_reversible.probe_purity`) and sees its
    forces change at identical positions.
    """


class UnsupportedConstraintError(ReversibilityError, ValueError):
    """A constraint that cannot be applied exactly in fixed point.

    Raised by the constructor; FixAtoms, FixCartesian, FixedPlane,
    FixedLine and FixCom are supported (ReversibleLangevin: FixAtoms,
    FixCartesian and FixCom).
    """


class CoarseQuantumError(ReversibilityError, ValueError):
    """A momentum quantum so coarse that it would visibly change the state.

    Raised by the constructor, before anything is changed, when snapping
    the momenta to the grid would move the kinetic energy by more than a
    tiny fraction or leave too few significant bits
    (:func:`ase_reversible.core.quanta.momentum_resolution_problem`).  The
    message says where the quantum came from (``momentum_quantum``, or a
    ``force_noise`` that raised it) and what to change.
    """


class RetraceLimitError(ReversibilityError, RuntimeError):
    """A step back past the point a thermostat's run can be retraced to.

    Raised by :class:`~ase_reversible.ReversibleLangevin` when a backward
    step would undo friction that was never applied (before the anchor of
    reversal); the step is not taken.
    """


class NonFiniteStateError(ReversibilityError, ValueError):
    """Positions or momenta that are NaN or infinite.

    Raised by the constructor (the atoms are left as they were), and at
    the next step, ``run`` or ``backpropagate`` when such values were set
    on the atoms between runs.  A fixed-point state cannot hold them, and
    the values they replaced are gone, so the integrator puts its last
    exact state back on the atoms (positions and momenta) and says so:
    ``reverse()`` and further runs then work as if the edit had not been
    made.
    """


class AnchorMovedWarning(UserWarning):
    """A change made around the run was taken: reversal starts anew there.

    Issued by :class:`~ase_reversible.ReversibleVerlet` at the next step (or
    ``backpropagate``) when the positions, momenta, masses, atomic
    numbers, cell, pbc, constraints, calculator or its parameters differ
    from what the integrator last saw, and when the size of ``dt`` changes
    after steps were taken.  The change is taken (positions and momenta
    snapped to the grid); reversal then leads back to that point
    (:attr:`~ase_reversible.md.base.ReversibleDynamics.anchor`), not
    beyond.  Also issued by the constructor when a restart record in
    ``atoms.info`` does not fit the atoms (new quanta are chosen).

    Within one run a kind of change is warned once, when it first happens;
    if it recurs (an observer that wraps the atoms at every step), one more
    warning at the end of the run gives the number of further steps.
    """


class MachineChangedWarning(AnchorMovedWarning):
    """A restart frame's forces are not those of the run that wrote it.

    Issued by the constructor of a reversible integrator resumed from a
    frame (with or without a :class:`~ase_reversible.ReversibleLangevin`
    buffer file) whose restart record holds a digest of the forces at the
    frame, when the forces computed here differ: this machine or software
    stack (CPU features, numpy, BLAS, thread counts, the calculator or its
    settings) computes other last bits.  Also issued when the record has
    no digest and was written on another platform.  The run from the
    frame on is exact and reversible to the frame, which is the anchor;
    running back past it leaves the path of the run that wrote it as soon
    as one rounded kick comes out otherwise (for ASE's EMT within a few
    steps; ASE's LennardJones was seen to come back all the same), so it
    cannot be trusted to reach that run's earlier states.  A Langevin
    buffer's way back is dropped: a step back past the frame raises
    :class:`RetraceLimitError`.  The message names both platforms.  To
    run back past the frame, run on the machine that wrote it (the
    Machines page of the documentation).
    """
