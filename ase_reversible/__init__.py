"""ase-reversible: molecular dynamics for ASE that runs backwards exactly.

>>> from ase_reversible import ReversibleVerlet
>>> dyn = ReversibleVerlet(atoms, 5 * ase.units.fs)   # doctest: +SKIP
>>> dyn.run(1000); dyn.reverse(); dyn.run(1000)       # doctest: +SKIP

leaves ``atoms`` bit for bit where the constructor put it.

Where things live: :mod:`.core` (the exact engine: codec, quanta,
variables, plans, compositions, restart record), :mod:`.md` (the ASE
integrators), :mod:`.purity` (forces as a pure function of positions),
:mod:`.adjoint` (gradients by retracing), :mod:`.calculators` (our own),
:mod:`.app` (systems, flipbook, scenes, demo, command line).
"""

from .errors import (AnchorMovedWarning, CoarseQuantumError,
                     ImpureForcesError, MachineChangedWarning,
                     NonFiniteForcesError, NonFiniteStateError,
                     QuantumRangeError, RetraceLimitError,
                     ReversibilityError,
                     UnstableIntegrationError, UnsupportedConstraintError)
from .adjoint import AnalyticHVP, FiniteDifferenceHVP, Gradients
from .app.flipbook import Flipbook
from .calculators import LennardJones, PendulumChain, SoftenedGravity
from .core.quanta import Grid
from .core.record import INFO_KEY  # noqa: F401  (the restart record's key)
from .md import (FixedPointState, ReversibleBussi, ReversibleIsotropicNPT,
                 ReversibleLangevin, ReversibleNose, ReversibleNPT,
                 ReversibleVerlet)
from .md.verdict import check_calculator
from .purity import CalculatorCheck, probe_purity

__version__ = '0.1.0'

__all__ = ['ReversibleVerlet', 'ReversibleLangevin', 'ReversibleBussi',
           'ReversibleNose', 'ReversibleIsotropicNPT', 'ReversibleNPT',
           'Grid', 'FixedPointState', 'probe_purity',
           'check_calculator', 'CalculatorCheck',
           'Gradients', 'LennardJones', 'PendulumChain', 'SoftenedGravity',
           'Flipbook', 'AnalyticHVP', 'FiniteDifferenceHVP',
           'AnchorMovedWarning', 'MachineChangedWarning',
           'ReversibilityError', 'QuantumRangeError',
           'NonFiniteForcesError', 'NonFiniteStateError',
           'RetraceLimitError', 'ImpureForcesError', 'CoarseQuantumError',
           'UnstableIntegrationError', 'UnsupportedConstraintError']
