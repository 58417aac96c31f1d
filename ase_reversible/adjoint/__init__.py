"""The reversible adjoint: gradients through a run by retracing it exactly.

Reverse-mode differentiation of a run needs the states of the forward run
in reverse order.  Usually they are stored (memory proportional to the
number of steps) or recomputed from checkpoints.  ReversibleVerlet instead
runs back: every state it meets on the way is bitwise the forward one, so
the adjoint is integrated along the exact forward path with memory that
does not depend on the number of steps (J. Stam, "An Exact Bitwise
Reversible Integrator", section "Application: Reversible Adjoint", eq.
adjPosVerlet).

The engine (:meth:`ase_reversible.core.engine.Engine.retrace`) runs the
plan backwards and, before undoing each sub-step, lets it pull the
cotangents back through itself: every sub-step kind brings its own adjoint
rule, so any plan can be differentiated.  The Hamiltonian sub-steps
(:mod:`ase_reversible.md.hamiltonian`) are linear in the variable they
update; with ``P`` the (orthogonal) constraint projection, ``m`` the masses, ``H``
the Hessian of the potential energy and ``a_x``, ``a_p`` the adjoints
(``dL/dx``, ``dL/dp``) ``[n_atoms, 3]``, its adjoint is::

    drift  x += c h P p / m     ->   a_p += c h P a_x / m
    kick   p += c h P F(x)      ->   a_x -= c h H(x) P a_p
                                     a_theta += c h (dF/dtheta)^T P a_p

applied in the reverse order of the forward sub-steps, each at the
positions that sub-step saw.  Rounding is not differentiated: the
gradient is that of the float-valued scheme, evaluated on the exact path,
so the only error is the adjoint integration's own floating point (and
that of the Hessian-vector products, see :mod:`.hessian`).

Kicks with no drift between them act at the same positions on the same
``a_p``; their products are merged into one (:meth:`Cotangents.defer`).  The kick-drift-kick scheme
thus needs one product per step (``steps + 1`` for a retrace, the first
kick of the run included), the drift-kick-drift scheme one per kick.

Momenta that the constraints hold (a fixed atom's) are not free: the
constructor projects them, and no step changes them.  The momentum
gradient returned is therefore projected too, so an optimiser sees no
direction it cannot move in.  Positions of fixed atoms stay in the
position gradient: where a fixed atom is pinned changes the forces on the
others.
"""

from .cotangents import Cotangents, Gradients
from .hessian import AnalyticHVP, FiniteDifferenceHVP
from .products import CalculatorProduct, HessianProduct, product_for
from .schedule import LossSchedule

__all__ = ['Cotangents', 'Gradients', 'AnalyticHVP', 'FiniteDifferenceHVP',
           'CalculatorProduct', 'HessianProduct', 'product_for',
           'LossSchedule']
