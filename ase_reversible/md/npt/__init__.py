"""ReversibleIsotropicNPT: constant pressure and temperature, run back
exactly.

The package: :mod:`.system` (the exact variables in scaled coordinates,
what the atoms show, the drift, kicks and piston), :mod:`.friction` (the
O step on the atoms and the piston), :mod:`.isotropic` (the integrator),
:mod:`.cell` (``ReversibleNPT``: the whole cell free, ASE's ``MTKNPT``),
:mod:`.nose` and :mod:`.cell_nose` (Nosé's chain instead of the Langevin
thermostat: ``thermostat='nose'``),
:mod:`.checks` (arguments, atoms, records and buffer files).

Andersen's barostat (H. C. Andersen, J. Chem. Phys. 72, 2384 (1980)) as an
extended Hamiltonian in scaled variables: the cell is ``lambda * cell0``,
the atoms sit at ``x = lambda * rho`` and carry ``p = pi / lambda``.  The
derivation (the Hamiltonian, its ensemble, its split into exact shears,
the piston's push from the stress, the barostat's mass and the gradients)
is in docs/pressure.md, "The derivation".
"""

from .cell import ReversibleNPT
from .isotropic import ENERGY_CHECK_INTERVAL, SCHEME, ReversibleIsotropicNPT
from .system import (LAMBDA_MIN, LAMBDA_QUANTUM, P_LAMBDA_BITS,
                     NPTHamiltonian, VirialKick, barostat_mass, cell_volume)

# No __all__: the API pages document each object once, in its own module,
# and an __all__ here would document them a second time on this page.
