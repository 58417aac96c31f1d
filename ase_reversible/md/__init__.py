"""The ASE adapters: integrators that are ``ase.md`` dynamics.

:class:`~.base.ReversibleDynamics` is the thin base (ASE's run loop, the
clock, the views of the state, ``backpropagate``), with the change contract
(:mod:`.changes`) and the restart record (:mod:`.restart`) as its parts;
:mod:`.admission` is what every constructor checks and chooses, and
:mod:`.verdict` runs it for :func:`~.verdict.check_calculator`;
:class:`~.verlet.ReversibleVerlet` declares NVE on it,
:class:`~.langevin.ReversibleLangevin`, :class:`~.bussi.ReversibleBussi`
and :class:`~.nose.ReversibleNose` NVT, :class:`~.npt.ReversibleIsotropicNPT`
and :class:`~.npt.ReversibleNPT` NPT.  :mod:`.hamiltonian` holds the drift
and kick, :mod:`.watch` what is checked around a run, :mod:`.constraints`
the exact constraint projections.
"""

from .base import ReversibleDynamics
from .state import FixedPointState
from .langevin import ReversibleLangevin
from .bussi import ReversibleBussi
from .nose import ReversibleNose
from .npt import ReversibleIsotropicNPT, ReversibleNPT
from .verlet import ReversibleVerlet

__all__ = ['ReversibleDynamics', 'ReversibleVerlet', 'ReversibleLangevin',
           'ReversibleBussi', 'ReversibleNose', 'ReversibleIsotropicNPT',
           'ReversibleNPT', 'FixedPointState']
