"""ReversibleNose: deterministic constant-temperature dynamics that runs back
exactly, with no memory that grows with the run.

Nosé's extended system (S. Nosé, J. Chem. Phys. 81, 511 (1984)), and a
chain of thermostats, split into exact shears.  docs/thermostats.md derives
the equations ("The extended system, split into shears", "A chain of
thermostats"), the ensemble, the degrees of freedom and the clock ("Which
ensemble").  :mod:`.thermostat` holds the rules every driver shares (the
masses, the quanta, the degrees of freedom), :mod:`.system` the extended
Hamiltonian and its sub-steps, :mod:`.dynamics` the integrator.
"""

# No __all__: the API pages document each object once, in its own module.
from .dynamics import ReversibleNose  # noqa: F401
