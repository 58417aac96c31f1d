"""ase-reversible: molecular dynamics for ASE that runs backwards exactly.

>>> from ase_reversible import ReversibleVerlet
>>> dyn = ReversibleVerlet(atoms, 5 * ase.units.fs)   # doctest: +SKIP
>>> dyn.run(1000); dyn.reverse(); dyn.run(1000)       # doctest: +SKIP

leaves ``atoms`` bit for bit where the constructor put it.
"""

from .errors import (CoarseQuantumError, ImpureForcesError,
                     NonFiniteForcesError,
                     QuantumRangeError, ReversibilityError,
                     UnstableIntegrationError, UnsupportedConstraintError)
from .adjoint import Gradients
from .calculators import LennardJones, PendulumChain, SoftenedGravity
from .fixedpoint import FixedPointState, Grid
from .flipbook import Flipbook
from .hessian import AnalyticHVP, FiniteDifferenceHVP
from .purity import probe_purity
from .verlet import AnchorMovedWarning, ReversibleVerlet

__version__ = '0.1.0'

__all__ = ['ReversibleVerlet', 'Grid', 'FixedPointState', 'probe_purity',
           'Gradients', 'LennardJones', 'PendulumChain', 'SoftenedGravity',
           'Flipbook', 'AnalyticHVP', 'FiniteDifferenceHVP',
           'AnchorMovedWarning', 'ReversibilityError', 'QuantumRangeError',
           'NonFiniteForcesError', 'ImpureForcesError', 'CoarseQuantumError',
           'UnstableIntegrationError', 'UnsupportedConstraintError']
