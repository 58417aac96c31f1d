"""Ready-made systems to browse: ``python -m ase_reversible flipbook SCENE``.

Each scene builder returns a :class:`Scene`: atoms with a calculator
attached, a time step, the steps per flipbook frame and a view.  The
``examples/`` scripts build the same kinds of system in full, for copying.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
from ase import units

from ..calculators import LennardJones, PendulumChain, SoftenedGravity
# The builders stay at their modules' paths: only the calculators are
# exported by the package.
from ..calculators import make_chain, make_ring
from .systems import (AR_EPSILON, AR_RC, AR_SIGMA, ICOSAHEDRON_SHELLS,
                      argon_cluster)
from .view import AtomsView


@dataclass
class Scene:
    """A system ready to run.

    ``timestep`` is in ASE time units; ``stride`` is steps per frame.
    """

    atoms: object
    timestep: float
    stride: int
    view: Callable
    description: str


def ring(n_atoms=100):
    """Gravitational collapse of a ring (J. Stam's first figure)."""
    import matplotlib
    atoms = make_ring(n_atoms, radius=10.0, jitter=0.05)
    atoms.calc = SoftenedGravity(G=1.0, softening=0.3)
    colors = matplotlib.colormaps['hsv'](np.arange(n_atoms) / n_atoms)
    return Scene(atoms, 0.002, 25, AtomsView('xy', colors=colors, size=18),
                 f'{n_atoms} bodies on a 10 Å ring, softened gravity '
                 '(G = 1 eV Å/amu², softening 0.3 Å)')


def chain(n_links=6):
    """A chaotic pendulum chain pinned at its top (the paper's web demo)."""
    atoms = make_chain(n_links, angle=90.0)
    atoms.calc = PendulumChain(stiffness=1000.0, gravity=1.0)
    bonds = np.column_stack([np.arange(n_links), np.arange(1, n_links + 1)])
    return Scene(atoms, 0.01, 10, AtomsView('xz', colors='tab:blue',
                                            size=25, bonds=bonds),
                 f'{n_links}-link pendulum chain released from horizontal')


def argon(n_atoms=55, temperature_K=60.0, seed=0):
    """A warm argon icosahedron (``n_atoms`` a magic size: 13, 55, 147,
    ...) with Lennard-Jones forces; ``temperature_K`` in K."""
    if n_atoms not in ICOSAHEDRON_SHELLS:
        raise ValueError(f'argon scene: n_atoms must be one of '
                         f'{tuple(ICOSAHEDRON_SHELLS)}, got {n_atoms}')
    atoms = argon_cluster(ICOSAHEDRON_SHELLS[n_atoms], temperature_K, seed)
    atoms.calc = LennardJones(epsilon=AR_EPSILON, sigma=AR_SIGMA, rc=AR_RC)
    return Scene(atoms, 5 * units.fs, 4, AtomsView('xy', size=60),
                 f'Ar{n_atoms} at {temperature_K:g} K, Lennard-Jones')


SCENES = {'ring': ring, 'chain': chain, 'argon': argon}
