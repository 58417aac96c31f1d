"""A pendulum chain: beads on stiff springs under gravity.

The model of the paper's keyframe-control example (J. Stam, "An Exact
Bitwise Reversible Integrator", section "Application: Reversible Adjoint /
Neural ODEs"): atoms ``0-1-2-...-(n-1)`` in index order, each linked to the
next by a harmonic spring, all pulled down along -z by uniform gravity.
Pin the chain by fixing atom 0 (``ase.constraints.FixAtoms([0])``, which
:class:`~ase_reversible.ReversibleVerlet` applies exactly); with stiff
springs it behaves as a multiple pendulum and, from two links on, is
chaotic.  :func:`make_chain` builds one.

Energy, with ``d_l = x[l+1] - x[l]`` the ``l``-th link and ``r_l = |d_l|``::

    E = sum_l k/2 (r_l - L)**2  +  sum_i m_i g z_i

``k``: ``stiffness`` (eV/Å²), ``L``: ``rest_length`` (Å), ``m_i``: the
atoms' masses (amu), ``g``: ``gravity`` (eV/(Å amu), i.e. Å per ASE time
unit squared: an ASE acceleration), ``z_i``: height (Å, zero at z = 0).

The model is differentiable to any order, so besides energy and forces the
calculator gives the exact Hessian-vector product
(:meth:`PendulumChain.hessian_vector_product`) the reversible adjoint uses.
Links are plain differences of positions: periodic boundary conditions are
ignored (a chain needs no images).

Array names follow :mod:`ase_reversible.calculators.base`, with links for
pairs -- ``_lc``: ``[n_links, 3]``, ``_l``: ``[n_links]`` with ``n_links =
n_atoms - 1`` -- and link ``l`` joins atoms ``l`` and ``l + 1``.
"""

from __future__ import annotations

import math

import numpy as np
from ase import Atoms
from ase.calculators.calculator import all_changes
from ase.constraints import FixAtoms

from ..core.portable import rowdot, rowsquare
from .base import ExactCalculator


class PendulumChain(ExactCalculator):
    """Harmonic springs between consecutive atoms, plus uniform gravity.

    Parameters
    ----------
    stiffness : float
        Spring constant ``k`` of every link, eV/Å² (> 0).  Default 1000:
        with 1 amu beads no mode is faster than ``2 sqrt(k/m)`` = 63 rad
        per ASE time unit (see :meth:`hessian_vector_product`), resolved
        by a step of 0.0125 (0.13 fs).
    rest_length : float
        Length ``L`` at which a link exerts no force, Å (>= 0).  Default 1.
    gravity : float
        Downward (-z) acceleration ``g``, eV/(Å amu) (ASE units; >= 0).
        Each atom feels ``-m g`` along z, with its mass from the atoms.
        Default 1: a 1 Å link swings with period ``2 pi sqrt(L/g)``, 6.3
        time units (64 fs).

    Gives ``energy`` (= ``free_energy``), ``energies`` (each link's energy
    split equally between its two atoms, plus the atom's own ``m g z``)
    and ``forces``; and :meth:`hessian_vector_product`.
    """

    implemented_properties = ['energy', 'free_energy', 'energies', 'forces']
    default_parameters = {'stiffness': 1000.0, 'rest_length': 1.0,
                          'gravity': 1.0}
    parameter_bounds = {'stiffness': 'positive',
                        'rest_length': 'non-negative',
                        'gravity': 'non-negative'}
    differentiable_parameters = ('stiffness', 'rest_length', 'gravity')
    # Gravity pulls each atom by its mass; ASE's default check ignores
    # masses.
    system_quantities = ('positions', 'masses', 'numbers')

    # Pure (see the base class): a closed-form function of the positions
    # and masses, with no neighbour list and no cache.

    # -- ASE calculator interface ---------------------------------------

    def calculate(self, atoms=None, properties=('energy',),
                  system_changes=all_changes):
        """ASE's calculator hook: fills ``self.results``.

        ``energy`` and ``free_energy`` (eV), ``energies`` ``[n_atoms]``
        (eV) and ``forces`` ``[n_atoms, 3]`` (eV/Å).  Raises ValueError if
        two neighbours coincide.
        """
        super().calculate(atoms, properties, system_changes)
        atoms = self.atoms
        k = self.parameters['stiffness']
        g = self.parameters['gravity']
        x_nc = atoms.positions
        m_n = atoms.get_masses()
        d_lc, r_l = _links(x_nc)
        stretch_l = r_l - self.parameters['rest_length']
        u_l = 0.5 * k * (stretch_l * stretch_l)
        # A stretched link pulls its first atom towards the second:
        # F_l = -dE/dx_l = k (r - L) d / r.
        t_lc = _tension(k * stretch_l, r_l, d_lc)
        f_nc = _onto_atoms(t_lc, len(atoms))
        f_nc[:, 2] -= m_n * g
        height_n = m_n * g * x_nc[:, 2]
        energies_n = height_n.copy()
        energies_n[:-1] += 0.5 * u_l
        energies_n[1:] += 0.5 * u_l
        energy = float(np.sum(u_l) + np.sum(height_n))
        self.store_results(energy, energies_n, f_nc)

    # -- derivatives ------------------------------------------------------

    def hessian_vector_product(self, atoms, v_nc):
        """``H v``, ``H`` the Hessian of the energy, eV/Å² x (unit of v).

        ``v_nc`` is ``[n_atoms, 3]``, the result too, at the atoms' current
        positions.  Gravity is linear in the positions and drops out.
        Each link couples its two atoms through the 3x3 block ``K = k (1 -
        L/r) I + k L d d^T / r³``, the derivative of its pull on its first
        atom with respect to ``d``.  Its eigenvalues, ``k`` and ``k (1 -
        L/r)``, are at most ``k`` in magnitude while every link is longer
        than ``L/2``: then no mode of a chain of beads of mass ``m`` is
        faster than ``2 sqrt(k/m)``, whatever its pose or speed.
        """
        v_nc = self.as_vector(atoms, v_nc)
        k = self.parameters['stiffness']
        rest = self.parameters['rest_length']
        d_lc, r_l = _links(atoms.positions)
        dv_lc = v_nc[1:] - v_nc[:-1]
        # With u' = k (r - L) and u'' = k: the tension k (r - L) d / r
        # changes along dv by (u'/r) dv + (u'' - u'/r) (d.dv) d / r².
        along_l = k * rest / (r_l * r_l * r_l) * rowdot(d_lc, dv_lc)
        kdv_lc = (k * (1.0 - rest / r_l))[:, None] * dv_lc \
            + along_l[:, None] * d_lc
        # K dv is the change of the pull on the first atom of the link,
        # i.e. -(H v) there; the second atom gets the opposite.
        return -_onto_atoms(kdv_lc, len(atoms))


    def _force_parameter_derivative(self, atoms, name):
        """``dF/d(name)`` ``[n_atoms, 3]`` at the atoms' positions: per
        unit of stiffness (Å), of rest length (eV/Å²) or of gravity (amu).
        """
        n = len(atoms)
        if name == 'gravity':
            df_nc = np.zeros((n, 3))
            df_nc[:, 2] = -atoms.get_masses()
            return df_nc
        d_lc, r_l = _links(atoms.positions)
        if name == 'stiffness':
            pull_l = r_l - self.parameters['rest_length']
        else:
            pull_l = np.full_like(r_l, -self.parameters['stiffness'])
        return _onto_atoms(_tension(pull_l, r_l, d_lc), n)


def _links(x_nc):
    """Link vectors ``d_lc = x[l+1] - x[l]`` (Å) and lengths ``r_l``."""
    d_lc = x_nc[1:] - x_nc[:-1]
    r_l = np.sqrt(rowsquare(d_lc))
    if np.any(r_l == 0.0):
        first = int(np.argmin(r_l))
        raise ValueError(f'Atoms {first} and {first + 1} coincide: a link '
                         'of zero length has no direction.')
    return d_lc, r_l


def _tension(pull_l, r_l, d_lc):
    """``pull_l d / r``: the force of each link on its first atom, eV/Å."""
    return (pull_l / r_l)[:, None] * d_lc


def _onto_atoms(t_lc, n):
    """``[n, 3]``: ``+t`` on each link's first atom, ``-t`` on its second."""
    return ExactCalculator.scatter_pairs(t_lc, np.arange(n - 1),
                                         np.arange(1, n), n)


def make_chain(n_links, link_length=1.0, mass=1.0, angle=90.0, symbol='X'):
    """A straight chain from the origin in the x-z plane, pinned there.

    Parameters
    ----------
    n_links : int
        Number of links (>= 1); the chain has ``n_links + 1`` atoms, atom
        0 at the origin.
    link_length : float
        Distance between neighbours, Å; use it as ``rest_length``.
    mass : float or array_like ``[n_links + 1]``
        amu.
    angle : float
        Direction of the chain in the x-z plane, degrees from straight
        down (-z) towards +x: 0 hangs at rest, 90 is horizontal.
    symbol : str
        Chemical symbol of the beads (``'X'``: a dummy; only the masses
        matter to :class:`PendulumChain`).

    Returns
    -------
    ase.Atoms
        Zero momenta, ``FixAtoms([0])``, ``pbc=False`` and a cubic cell
        centred on the pin, big enough to hold the chain in any pose (for
        viewers and file formats that want one).
    """
    n_links = int(n_links)
    if n_links < 1:
        raise ValueError(f'A chain needs at least one link, got {n_links}')
    link_length = float(link_length)
    if not (math.isfinite(link_length) and link_length > 0):
        raise ValueError(f'link_length must be positive (Å), got '
                         f'{link_length!r}')
    theta = math.radians(angle)
    direction_c = np.array([math.sin(theta), 0.0, -math.cos(theta)])
    # cos(pi/2) is 6e-17, not 0: make horizontal and vertical chains exact.
    direction_c[np.abs(direction_c) < 1e-15] = 0.0
    s_n = link_length * np.arange(n_links + 1)
    atoms = Atoms([symbol] * (n_links + 1),
                  positions=s_n[:, None] * direction_c, pbc=False)
    atoms.set_masses(np.broadcast_to(np.asarray(mass, dtype=float),
                                     (n_links + 1,)).copy())
    reach = n_links * link_length + 1.0
    atoms.set_cell(2 * reach * np.eye(3))
    atoms.set_celldisp([-reach, -reach, -reach])
    atoms.set_momenta(np.zeros((n_links + 1, 3)))
    atoms.set_constraint(FixAtoms([0]))
    return atoms
