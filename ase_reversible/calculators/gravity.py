"""Softened pairwise gravity: the force of the paper's collapsing ring.

Every pair of atoms attracts with Newton's law, its singularity smoothed
over a length ``eps`` (Plummer softening)::

    E = - sum_{i<j} G m_i m_j / sqrt(r_ij**2 + eps**2)

so the pull of ``j`` on ``i`` is ``G m_i m_j d / (r**2 + eps**2)**1.5``
with ``d = x_j - x_i``.  Without ``eps`` two atoms meeting head on would
feel unbounded forces; with it, a close pass is a smooth swing that a time
step of a fraction of ``sqrt(eps**3 / (G m))`` resolves.

Units are ASE's: ``G`` in eV Å / amu², ``eps`` in Å, masses from the atoms
(amu).  With ``G = 1``, a 1 amu atom at 1 Å from another is accelerated at
1 Å per ASE time unit squared.  Periodic images are ignored: gravity has
no cut-off, and a ring or cluster in vacuum needs none.

Every pair is summed, each once, in the fixed order of
:func:`numpy.triu_indices`, and pair terms go onto the atoms in that order
(:meth:`ExactCalculator.scatter_pairs
<ase_reversible.calculators.base.ExactCalculator.scatter_pairs>`): the
forces are a pure function of the positions, reproducible bit for bit, so
:class:`~ase_reversible.ReversibleVerlet` trusts them without a probe.
The cost is O(n_atoms²), fine up to a few hundred atoms.

Array names follow :mod:`ase_reversible.calculators.base`; ``i_p < j_p``
are the two atoms of each pair and ``d_pc = x[j] - x[i]``.
"""

from __future__ import annotations

import math

import numpy as np
from ase.calculators.calculator import all_changes

from ..core.portable import rowdot, rowsquare
from .base import ExactCalculator


class SoftenedGravity(ExactCalculator):
    """Newtonian attraction between every pair of atoms, softened.

    Parameters
    ----------
    G : float
        Gravitational constant, eV Å / amu² (> 0).  Default 1.
    softening : float
        Plummer length ``eps``, Å (> 0).  Default 0.5.

    Gives ``energy`` (= ``free_energy``), ``energies`` (each pair's energy
    split equally between its atoms) and ``forces``, eV/Å; and the exact
    :meth:`hessian_vector_product` for
    :meth:`~ase_reversible.ReversibleVerlet.backpropagate`.
    """

    implemented_properties = ['energy', 'free_energy', 'energies', 'forces']
    default_parameters = {'G': 1.0, 'softening': 0.5}
    differentiable_parameters = ('G', 'softening')
    parameter_bounds = {'G': 'positive', 'softening': 'positive'}
    # The pull of a pair is proportional to both masses; ASE's default
    # check ignores masses.
    system_quantities = ('positions', 'masses', 'numbers')

    # Pure (see the base class): a closed-form sum over all pairs in a
    # fixed order, with no neighbour list and no history.

    def _forget(self):
        self._pairs = (0, np.empty(0, int), np.empty(0, int))

    # -- ASE calculator interface ---------------------------------------

    def calculate(self, atoms=None, properties=('energy',),
                  system_changes=all_changes):
        """Energy (eV), per-atom energies (eV) and forces ``[n_atoms, 3]``
        (eV/Å), all at once."""
        super().calculate(atoms, properties, system_changes)
        atoms = self.atoms
        n = len(atoms)
        i_p, j_p, d_pc, s_p, gmm_p = self._pair_terms(atoms)
        inv_root_p = 1.0 / np.sqrt(s_p)
        u_p = -gmm_p * inv_root_p
        t_pc = (gmm_p * inv_root_p / s_p)[:, None] * d_pc
        f_nc = self.scatter_pairs(t_pc, i_p, j_p, n)
        energies_n = self.split_pair_energies(u_p, i_p, j_p, n)
        self.store_results(float(np.sum(u_p)), energies_n, f_nc)

    # -- derivatives ------------------------------------------------------

    def hessian_vector_product(self, atoms, v_nc):
        """``H v`` at the atoms' positions, eV/Å² x (unit of ``v``).

        ``v_nc`` and the result are ``[n_atoms, 3]``.  The pull of a pair
        on its first atom, ``t = w d`` with ``w = G m m s**-1.5`` and ``s =
        r**2 + eps**2``, changes along ``dv = v_j - v_i`` by ``w dv - 3 G m
        m s**-2.5 (d . dv) d``; ``H v`` is minus the change of the forces.
        """
        v_nc = self.as_vector(atoms, v_nc)
        i_p, j_p, d_pc, s_p, gmm_p = self._pair_terms(atoms)
        dv_pc = v_nc[j_p] - v_nc[i_p]
        w_p = gmm_p / (s_p * np.sqrt(s_p))
        along_p = 3.0 * w_p / s_p * rowdot(d_pc, dv_pc)
        kdv_pc = w_p[:, None] * dv_pc - along_p[:, None] * d_pc
        return -self.scatter_pairs(kdv_pc, i_p, j_p, len(atoms))

    def _force_parameter_derivative(self, atoms, name):
        """``dF/dG`` (amu² / Å², the forces over ``G``) or ``dF/d eps``
        (eV/Å²): the pull ``G m m s**-1.5 d`` changes with ``eps`` by ``-3
        eps G m m s**-2.5 d``."""
        i_p, j_p, d_pc, s_p, gmm_p = self._pair_terms(atoms)
        w_p = 1.0 / (s_p * np.sqrt(s_p))
        if name == 'G':
            w_p *= gmm_p / self.parameters['G']
        else:
            w_p *= -3.0 * self.parameters['softening'] * gmm_p / s_p
        return self.scatter_pairs(w_p[:, None] * d_pc, i_p, j_p, len(atoms))

    def _pair_terms(self, atoms):
        n = len(atoms)
        if self._pairs[0] != n:
            self._pairs = (n, *np.triu_indices(n, k=1))
        _, i_p, j_p = self._pairs
        x_nc = atoms.positions
        m_n = atoms.get_masses()
        d_pc = x_nc[j_p] - x_nc[i_p]
        eps = self.parameters['softening']
        s_p = rowsquare(d_pc) + eps * eps
        gmm_p = self.parameters['G'] * m_n[i_p] * m_n[j_p]
        return i_p, j_p, d_pc, s_p, gmm_p


def make_ring(n_atoms, radius=10.0, mass=1.0, symbol='X', spin=0.0,
              jitter=0.0, seed=0):
    """Atoms evenly spaced on a circle in the x-y plane, centred on 0.

    Parameters
    ----------
    n_atoms : int
        Number of atoms (>= 2).
    radius : float
        Å.
    mass : float
        amu, every atom.
    symbol : str
        Chemical symbol (``'X'``, a dummy: only masses matter to
        :class:`SoftenedGravity`).
    spin : float
        Tangential speed, Å per ASE time unit, anticlockwise seen from +z.
    jitter : float
        Random in-plane displacement of each atom, at most this many Å
        along x and y, so the collapse is not perfectly symmetric.
    seed : int
        For the jitter.

    Returns
    -------
    ase.Atoms
        ``pbc=False``, a cubic cell of side ``4 * radius`` centred on the
        ring (for viewers), momenta set, z = 0 for every atom (the motion
        stays in the plane exactly: the forces have no z component).
    """
    from ase import Atoms
    n_atoms = int(n_atoms)
    if n_atoms < 2:
        raise ValueError(f'A ring needs at least 2 atoms, got {n_atoms}')
    radius = float(radius)
    if not (math.isfinite(radius) and radius > 0):
        raise ValueError(f'radius must be positive (Å), got {radius!r}')
    phi_n = 2 * np.pi * np.arange(n_atoms) / n_atoms
    x_nc = np.zeros((n_atoms, 3))
    x_nc[:, 0] = radius * np.cos(phi_n)
    x_nc[:, 1] = radius * np.sin(phi_n)
    if jitter:
        rng = np.random.default_rng(seed)
        x_nc[:, :2] += rng.uniform(-jitter, jitter, (n_atoms, 2))
    atoms = Atoms([symbol] * n_atoms, positions=x_nc, pbc=False)
    atoms.set_masses(np.full(n_atoms, float(mass)))
    v_nc = np.zeros((n_atoms, 3))
    v_nc[:, 0] = -spin * np.sin(phi_n)
    v_nc[:, 1] = spin * np.cos(phi_n)
    atoms.set_momenta(atoms.get_masses()[:, None] * v_nc)
    side = 4 * radius
    atoms.set_cell(side * np.eye(3))
    atoms.set_celldisp([-side / 2] * 3)
    return atoms
