"""Exceptions raised by ase-reversible.

Every error is raised *before* the offending update is committed: after
catching one, the integrator still holds a state that runs back exactly to
where reversal was last anchored.
"""


class ReversibilityError(Exception):
    """Base class of the errors specific to ase-reversible."""


class QuantumRangeError(ReversibilityError, OverflowError):
    """A position or momentum would leave the range of the fixed-point grid."""


class NonFiniteForcesError(ReversibilityError, FloatingPointError):
    """The calculator returned NaN or infinite forces."""


class UnstableIntegrationError(ReversibilityError, RuntimeError):
    """The total energy drifted beyond its tolerance: the run is blowing up."""


class ImpureForcesError(ReversibilityError, RuntimeError):
    """The calculator's forces are not a pure function of the positions."""


class UnsupportedConstraintError(ReversibilityError, ValueError):
    """A constraint that cannot be applied exactly in fixed point."""
