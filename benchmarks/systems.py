"""Systems and calculators the benchmarks use beyond ase_reversible.app.systems.

The standard argon and copper systems, the argon Lennard-Jones parameters
and ``thermalize`` come from ``ase_reversible.app.systems``; what only the
benchmarks need is built here, once.
"""

from __future__ import annotations

import functools

import asap3
import numpy as np
from ase import Atoms
from ase.build import bulk
from ase.calculators.calculator import Calculator, all_changes
from ase.calculators.emt import EMT

from ase_reversible.app.systems import (AR_EPSILON, AR_RC, AR_SIGMA,
                                        argon_lj, thermalize)

#: Copper's lattice constant in ase.build.bulk, Å, and its bond length.
CU_LATTICE = 3.61
CU_BOND = CU_LATTICE / np.sqrt(2)

#: RGL (Gupta) parameters for copper of Cleri and Rosato, Phys. Rev. B 48,
#: 22 (1993), and the lattice constant they imply (sqrt(2) * r0).
CU_RGL = dict(p=10.960, q=2.278, a=0.0855, xi=1.224, r0=2.556)
CU_RGL_LATTICE = 3.615


def asap3_argon_lj(cutoff=AR_RC):
    """A constructor of asap3's LennardJones with the argon parameters.

    A partial rather than a calculator: asap3 calculators cannot be
    pickled, their constructor with its arguments can (savings.py hands it
    to worker processes that must not import this module).
    """
    return functools.partial(asap3.LennardJones, [18], [AR_EPSILON],
                             [AR_SIGMA], rCut=cutoff, modified=True)


def copper_rgl():
    return asap3.RGL(['Cu'], **CU_RGL)


#: Fresh calculators by the labels the tables use.
CALCULATORS = {
    'ASE LJ': argon_lj,
    'asap3 LJ': asap3_argon_lj(),
    'ASE EMT': EMT,
    'asap3 EMT': asap3.EMT,
}


def rgl_copper_crystal(repeat, temperature_K, seed=0):
    """Periodic fcc copper at the RGL potential's own lattice constant."""
    atoms = bulk('Cu', 'fcc', a=CU_RGL_LATTICE, cubic=True) * repeat
    return thermalize(atoms, temperature_K, seed)


def argon_fluid(n_atoms, cell_length, temperature_K, seed=0):
    """``n_atoms`` on a simple cubic lattice in a periodic cube."""
    k = int(np.ceil(n_atoms ** (1 / 3)))
    sites = (np.indices((k, k, k)).reshape(3, -1).T[:n_atoms] + 0.5) / k
    atoms = Atoms(f'Ar{n_atoms}', scaled_positions=sites,
                  cell=[cell_length] * 3, pbc=True)
    return thermalize(atoms, temperature_K, seed)


def pair(symbol, gap):
    """Two atoms at rest ``gap`` Å apart in 10 Å of vacuum."""
    atoms = Atoms(symbol * 2, positions=[(0, 0, 0), (gap, 0, 0)])
    atoms.center(vacuum=10.0)
    return atoms


def copper_bulk_contact(fraction):
    """Perfect Cu bulk (108 atoms) with atom 0 moved towards a neighbour
    until they are ``fraction`` of the bond length apart."""
    atoms = bulk('Cu', cubic=True) * (3, 3, 3)
    vectors = atoms.get_distances(0, range(1, len(atoms)), mic=True,
                                  vector=True)
    nearest = vectors[np.argmin(np.linalg.norm(vectors, axis=1))]
    atoms.positions[0] += (1 - fraction) * nearest
    return atoms


class CachedForces(Calculator):
    """A calculator whose force call costs next to nothing: zero forces and
    energy, computed once, returned for any positions.

    It still is a calculator behind ``atoms.get_forces``, with a cache as
    cheap to check as asap3's: the stored results are reused while the
    positions are bitwise those of the last calculation (the only thing the
    integrators change), and "computed" again -- copied, nothing else --
    when they are not.  ASE's own ``check_state`` would compare the whole
    Atoms with ``np.allclose`` at ~0.2 ms a call and bury the integrators'
    work under it.  With zero forces the atoms fly freely: the energy is
    exactly conserved (the energy check never trips) and the positions
    stay in range for the lengths of runs measured; numpy's arithmetic
    costs the same whatever the values.  Declared pure, so
    ReversibleVerlet's ``force_purity='auto'`` takes it as it is.
    """

    implemented_properties = ('energy', 'forces')
    forces_are_pure = True

    def __init__(self, n_atoms):
        super().__init__()
        self._fixed = {'energy': 0.0, 'forces': np.zeros((n_atoms, 3))}
        self._x_nc = None  # positions of the last calculation

    def check_state(self, atoms, tol=1e-15):
        x_nc = atoms.arrays['positions']
        if (self._x_nc is not None and x_nc.shape == self._x_nc.shape
                and x_nc.tobytes() == self._x_nc.tobytes()):
            return []
        return ['positions']

    def calculate(self, atoms=None, properties=('forces',),
                  system_changes=all_changes):
        self._x_nc = atoms.arrays['positions'].copy()
        self.results = dict(self._fixed)
