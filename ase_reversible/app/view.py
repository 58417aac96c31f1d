"""How the flipbook and the scenes draw atoms: discs projected on a plane.

Kept apart from :mod:`ase_reversible.app.flipbook` so that the scenes can
build their views without importing the flipbook, and the flipbook's
command line can import the scenes without a cycle.

matplotlib is imported only when something is drawn.
"""

from __future__ import annotations

import numpy as np

#: Plane name -> indices of the two Cartesian axes shown.
PLANES = {'xy': (0, 1), 'xz': (0, 2), 'yz': (1, 2)}


class AtomsView:
    """Draws atoms as discs projected on a plane of Cartesian axes.

    Parameters
    ----------
    plane : {'xy', 'xz', 'yz'}
        The two axes shown, Å.
    colors : array_like, optional
        One matplotlib colour per atom (``[n_atoms]`` names or
        ``[n_atoms, 3 or 4]`` RGB(A) in 0..1).  Default: Jmol colours by
        element.
    size : float or array_like ``[n_atoms]``
        Marker area, points².
    bonds : array_like ``[n_bonds, 2]``, optional
        Pairs of atom indices joined by a line (a chain's links).

    Call it as ``view(ax, atoms)`` on a cleared matplotlib axes.
    """

    def __init__(self, plane='xy', colors=None, size=30.0, bonds=None):
        if plane not in PLANES:
            raise ValueError(f'plane must be one of {tuple(PLANES)}, got '
                             f'{plane!r}')
        self.plane = plane
        self.colors = colors
        self.size = size
        self.bonds = None if bonds is None else np.asarray(bonds, dtype=int)
        if self.bonds is not None and (self.bonds.ndim != 2
                                       or self.bonds.shape[1] != 2):
            raise ValueError('bonds must be pairs of atom indices, shape '
                             f'[n_bonds, 2]; got shape {self.bonds.shape}')

    def axes(self):
        """Indices of the two Cartesian axes shown."""
        return PLANES[self.plane]

    def __call__(self, ax, atoms):
        """Draw ``atoms`` (positions in Å) on the matplotlib axes ``ax``."""
        a, b = self.axes()
        x_nc = atoms.positions
        if self.bonds is not None and len(self.bonds):
            segments = x_nc[self.bonds][:, :, [a, b]]
            from matplotlib.collections import LineCollection
            ax.add_collection(LineCollection(segments, colors='0.35',
                                             linewidths=1.5, zorder=1))
        colors = self.colors
        if colors is None:
            from ase.data.colors import jmol_colors
            colors = jmol_colors[atoms.numbers]
        ax.scatter(x_nc[:, a], x_nc[:, b], s=self.size, c=colors,
                   edgecolors='k', linewidths=0.3, zorder=2)
        ax.set_xlabel(f'{self.plane[0]} (Å)')
        ax.set_ylabel(f'{self.plane[1]} (Å)')
