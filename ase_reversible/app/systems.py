"""Ready-made systems: argon and copper with thermal momenta from a seed.

The one place where the library's tests, benchmarks, demo, scenes and
examples get their standard systems and the argon Lennard-Jones
parameters, so that "Ar55 at 120 K" means the same atoms everywhere.
"""

from __future__ import annotations

import numpy as np
from ase.build import bulk
from ase.cluster import Icosahedron
from ase.md import velocitydistribution

#: Argon Lennard-Jones well depth (eV), diameter (Å) and cut-off (Å).
AR_EPSILON, AR_SIGMA, AR_RC = 0.0104, 3.4, 8.5
#: Lattice constant of solid argon, Å.
AR_LATTICE = 5.26
#: Icosahedron shells for each magic cluster size.
ICOSAHEDRON_SHELLS = {13: 2, 55: 3, 147: 4, 309: 5, 561: 6}


def thermalize(atoms, temperature_K, seed=0):
    """Give ``atoms`` Maxwell-Boltzmann momenta at exactly ``temperature_K``.

    Drawn from ``numpy.random.default_rng(seed)``; returns the atoms.
    """
    rng = np.random.default_rng(seed)
    if hasattr(velocitydistribution, 'thermalize_momenta'):  # ASE >= 3.29
        velocitydistribution.thermalize_momenta(
            atoms, temperature_K, exact_temperature=True, rng=rng)
    else:
        velocitydistribution.MaxwellBoltzmannDistribution(
            atoms, temperature_K=temperature_K, rng=rng, force_temp=True)
    return atoms


def argon_lj():
    """ASE's LennardJones with the argon parameters above."""
    from ase.calculators.lj import LennardJones
    return LennardJones(sigma=AR_SIGMA, epsilon=AR_EPSILON, rc=AR_RC)


def argon_cluster(shells, temperature_K, seed=0):
    """Argon icosahedron in 10 Å of vacuum (shells 2, 3, 4: 13, 55, 147
    atoms), no calculator.  It has a cell, which asap3 needs even without
    periodic boundaries."""
    atoms = Icosahedron('Ar', shells, latticeconstant=AR_LATTICE)
    atoms.center(vacuum=10.0)
    return thermalize(atoms, temperature_K, seed)


def argon_bulk(size=(3, 3, 3), temperature_K=80, seed=0):
    """Periodic fcc argon, ``4 * prod(size)`` atoms, no calculator."""
    atoms = bulk('Ar', 'fcc', a=AR_LATTICE, cubic=True) * size
    return thermalize(atoms, temperature_K, seed)


def copper_cluster(shells=3, temperature_K=600, seed=0):
    """Copper icosahedron in 10 Å of vacuum, no calculator."""
    atoms = Icosahedron('Cu', shells)
    atoms.center(vacuum=10.0)
    return thermalize(atoms, temperature_K, seed)


def copper_bulk(size=(3, 3, 3), temperature_K=600, seed=0, rattle=0.05):
    """Periodic fcc copper, ``4 * prod(size)`` atoms, positions rattled by
    ``rattle`` Å rms, no calculator."""
    atoms = bulk('Cu', cubic=True) * size
    if rattle:
        atoms.rattle(rattle, seed=seed)
    return thermalize(atoms, temperature_K, seed)
