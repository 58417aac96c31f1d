"""The ASE adapters: integrators that are ``ase.md`` dynamics.

:class:`~.base.ReversibleDynamics` is the thin base (ASE's run loop, the
change contract, the clock, ``backpropagate``);
:class:`~.verlet.ReversibleVerlet` declares NVE on it,
:class:`~.langevin.ReversibleLangevin` and :class:`~.nose.ReversibleNose`
NVT, :class:`~.npt.ReversibleIsotropicNPT` NPT.  :mod:`.hamiltonian` holds
the drift and kick, :mod:`.watch` what is
checked around a run, :mod:`.constraints` the exact constraint
projections.
"""

from .base import ReversibleDynamics
from .state import FixedPointState
from .langevin import ReversibleLangevin
from .nose import ReversibleNose
from .npt import ReversibleIsotropicNPT
from .verlet import ReversibleVerlet

__all__ = ['ReversibleDynamics', 'ReversibleVerlet', 'ReversibleLangevin',
           'ReversibleNose', 'ReversibleIsotropicNPT', 'FixedPointState']
