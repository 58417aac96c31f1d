"""Sub-steps and plans: what a dynamics declares.

A *sub-step* is one exact update: it adds to one variable the odd
rounding of a function of variables it does not change (a shear), times a
coefficient ``c h``.  Run with ``-c h`` at the same values of those other
variables, it subtracts exactly what it added.

A *scheme* is a palindrome of ``(sub-step, fraction of the time step)``,
e.g. kick 1/2, drift 1, kick 1/2.  A *plan* is a scheme composed to
higher order (:mod:`.compositions`) with neighbouring sub-steps of the
same kind merged.  Because a plan reads the same backwards, the plan run
with ``-h`` is the exact inverse of the plan run with ``h``.
"""

from __future__ import annotations

from .compositions import Composition


class SubStep:
    """An exact update of one variable; subclasses implement :meth:`apply`.

    A sub-step may keep caches (forces at the positions it last saw):
    :meth:`checkpoint` and :meth:`rollback` are called with the variables'
    so that a failed step leaves no stale cache behind.
    """

    def prepare(self, ch: float):
        """Whatever :meth:`apply` needs for the coefficient ``ch`` (``c h``,
        the fraction times the time step), computed once per time step."""
        return ch

    def apply(self, prepared):
        """Add the rounded increment for ``prepared`` to the variable."""
        raise NotImplementedError

    def adjoint(self, cotangents, ch: float):
        """Pull ``cotangents`` (dL/d variable, by name) back through this
        sub-step with coefficient ``ch``, before it is undone."""
        raise NotImplementedError(
            f'{type(self).__name__} has no adjoint: backpropagate is not '
            'available for this dynamics.')

    def checkpoint(self):
        """Remember the caches' state (called before every step)."""

    def rollback(self):
        """Forget anything cached during a step that failed."""


def compose(scheme, composition: Composition):
    """The plan of a composed step: ``((sub-step, fraction), ...)``, merged.

    ``scheme`` is the second-order palindrome of ``(sub-step, fraction)``.
    Each stage of the composition scales it by its ``g_i``; neighbours that
    are the same sub-step are merged by adding their fractions (kick-drift-
    kick stages share their kicks, so an ``s``-stage composition costs
    ``s`` force calls per step).  Float addition commutes, so the merged
    sequence stays a palindrome bit for bit.
    """
    merged = []
    for g in composition.fractions:
        for substep, c in scheme:
            if merged and merged[-1][0] is substep:
                merged[-1] = (substep, merged[-1][1] + c * g)
            else:
                merged.append((substep, c * g))
    plan = tuple(merged)
    assert all(a[0] is b[0] and a[1] == b[1]
               for a, b in zip(plan, plan[::-1])), \
        'a composed step must be a palindrome'
    return plan
