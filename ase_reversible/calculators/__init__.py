"""The package's calculators: pure forces, exact state checks, analytic
Hessian-vector products.

:class:`LennardJones` (argon and the like, with parameter derivatives for
the adjoint), :class:`PendulumChain` (beads on springs under gravity, with
:func:`make_chain`) and :class:`SoftenedGravity` (with :func:`make_ring`),
all built on :class:`~ase_reversible.calculators.base.ExactCalculator`.
"""

from .base import ExactCalculator
from .chain import PendulumChain, make_chain
from .gravity import SoftenedGravity, make_ring
from .lennardjones import LennardJones

__all__ = ['ExactCalculator', 'LennardJones', 'PendulumChain',
           'SoftenedGravity', 'make_chain', 'make_ring']
