"""Ready-made systems: argon, copper and rigid water with thermal
momenta from a seed.

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


#: Spacing of the water lattice of :func:`water_box`, Å (about liquid
#: water's density, 1 g/cm**3 at 3.1 Å).
WATER_SPACING = 3.1


def water_bonds(n):
    """ASE's ``FixBondLengths`` on the three bonds of each of ``n`` waters
    (atoms O, H, H in order): rigid TIP3P water."""
    from ase.constraints import FixBondLengths
    return FixBondLengths([(3 * i + a, 3 * i + b) for i in range(n)
                           for a, b in ((0, 1), (0, 2), (1, 2))])


def water_box(side, temperature_K=300, seed=0, rc=None):
    """``side**3`` rigid TIP3P waters (ASE's geometry and calculator),
    periodic, on a lattice of :data:`WATER_SPACING` Å, each turned at
    random, with Maxwell-Boltzmann momenta at ``temperature_K`` (K; not
    yet rigid: an integrator takes their rigid part) drawn from ``seed``.
    ``rc``: TIP3P's cut-off, Å; default 6 Å or just under half the box.
    """
    from ase import Atoms, units
    from ase.build import molecule
    from ase.calculators.tip3p import TIP3P, angleHOH, rOH
    water = molecule('H2O')
    water.set_angle(1, 0, 2, angleHOH)
    water.set_distance(0, 1, rOH, fix=0)
    water.set_distance(0, 2, rOH, fix=0)
    rng = np.random.default_rng(seed)
    box = Atoms()
    for index in np.ndindex(side, side, side):
        m = water.copy()
        m.rotate(rng.uniform(0, 360), rng.normal(size=3))
        m.translate(WATER_SPACING * np.array(index))
        box += m
    box.cell = [WATER_SPACING * side] * 3
    box.pbc = True
    box.set_constraint(water_bonds(side**3))
    masses = box.get_masses()[:, None]
    box.set_momenta(np.sqrt(masses * units.kB * temperature_K)
                    * rng.normal(size=(len(box), 3)))
    if rc is None:
        rc = min(6.0, 0.5 * WATER_SPACING * side - 0.01)
    box.calc = TIP3P(rc=rc)
    return box

