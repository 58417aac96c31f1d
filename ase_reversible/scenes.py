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

from .flipbook import AtomsView


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
    from .gravity import SoftenedGravity, make_ring
    atoms = make_ring(n_atoms, radius=10.0, jitter=0.05)
    atoms.calc = SoftenedGravity(G=1.0, softening=0.3)
    colors = matplotlib.colormaps['hsv'](np.arange(n_atoms) / n_atoms)
    return Scene(atoms, 0.002, 25, AtomsView('xy', colors=colors, size=18),
                 f'{n_atoms} bodies on a 10 Å ring, softened gravity '
                 '(G = 1 eV Å/amu², softening 0.3 Å)')


def chain(n_links=6):
    """A chaotic pendulum chain pinned at its top (the paper's web demo)."""
    from .chain import PendulumChain, make_chain
    atoms = make_chain(n_links, angle=90.0)
    atoms.calc = PendulumChain(stiffness=1000.0, gravity=1.0)
    bonds = np.column_stack([np.arange(n_links), np.arange(1, n_links + 1)])
    return Scene(atoms, 0.01, 10, AtomsView('xz', colors='tab:blue',
                                            size=25, bonds=bonds),
                 f'{n_links}-link pendulum chain released from horizontal')


def argon(n_atoms=55, temperature_K=60.0, seed=0):
    """A warm argon icosahedron with Lennard-Jones forces."""
    from ase.cluster import Icosahedron
    from .demo import thermalize
    from .lennardjones import LennardJones
    shells = {13: 2, 55: 3, 147: 4}
    if n_atoms not in shells:
        raise ValueError(f'argon scene: n_atoms must be one of '
                         f'{tuple(shells)}, got {n_atoms}')
    atoms = Icosahedron('Ar', shells[n_atoms], latticeconstant=5.26)
    atoms.center()
    thermalize(atoms, temperature_K, seed)
    atoms.calc = LennardJones(epsilon=0.0104, sigma=3.4, rc=8.5)
    return Scene(atoms, 5 * units.fs, 4, AtomsView('xy', size=60),
                 f'Ar{n_atoms} at {temperature_K:g} K, Lennard-Jones')


SCENES = {'ring': ring, 'chain': chain, 'argon': argon}
