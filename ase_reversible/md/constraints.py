"""Constraints applied exactly: linear projections of every increment.

A constraint keeps reversal exact when it acts on each sub-step's increment
as a linear projection ``P`` with ``P(-y) == -P(y)`` bitwise: the drift then
adds ``rint(P(h p / m))``, a function of the momenta only, and the kick adds
``rint(P(h F(x)))``, a function of the positions only.  FixAtoms and
FixCartesian zero components, so constrained coordinates never change, not
even by a quantum.  FixedPlane and FixedLine project onto a plane or line;
as their directions are rarely grid-aligned, rounding lets atoms leave the
plane or line by a few quanta (a random walk of ~1e-12 Å per step).

Constraints that move atoms by a float correction (FixCom, FixBondLengths,
Hookean, ...) would add an increment that is not a function of the other
variable, so they are refused.
"""

from __future__ import annotations

from ase.constraints import FixAtoms, FixCartesian, FixedLine, FixedPlane

from ..errors import UnsupportedConstraintError

SUPPORTED = (FixAtoms, FixCartesian, FixedPlane, FixedLine)


def no_projection(y_nc):
    """The projection without constraints: leaves ``y_nc`` as it is."""
    return None


def constraint_projection(atoms):
    """In-place projection ``project(y_nc)`` for the atoms' constraints.

    Returns a callable that projects an increment ``y_nc`` ``[n_atoms, 3]``
    (any unit) in place and returns None.  Raises
    :class:`UnsupportedConstraintError` for constraints that are not linear
    projections.
    """
    constraints = list(atoms.constraints)
    for c in constraints:
        if not isinstance(c, SUPPORTED):
            names = ', '.join(cls.__name__ for cls in SUPPORTED)
            raise UnsupportedConstraintError(
                f'{type(c).__name__} cannot be applied exactly in fixed point '
                'and would break exact reversal. Supported constraints: '
                f'{names}. Remove it (del atoms.constraints) or use '
                'VelocityVerlet for this system.')
    if not constraints:
        return no_projection

    def project(y_nc):
        for c in constraints:
            c.adjust_forces(atoms, y_nc)

    return project
