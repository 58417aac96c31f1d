"""A Lennard-Jones calculator with exact Hessian-vector products.

The reversible adjoint (:mod:`ase_reversible.adjoint`) needs, besides the
forces, products of the Hessian with a vector and the derivatives of the
forces with respect to the potential's parameters.  This calculator gives
all three analytically, and its forces are a pure function of the
positions (see ``LennardJones.forces_are_pure``), so
:class:`~ase_reversible.ReversibleVerlet` needs no force-purity remedy.

Pair energy, with ``s = sigma / r`` and a switch that takes it smoothly to
zero between ``ro`` and ``rc``::

    u(r) = 4 epsilon (s**12 - s**6) S(t),   t = (r - ro) / (rc - ro),
    S(t) = 1 - t**3 (10 - 15 t + 6 t**2)    (0 <= t <= 1)

``S`` is the quintic smoothstep: ``u``, its first and its second derivative
are continuous at both ends, so the forces are continuously differentiable
and the map from the start of a run to its end is too -- which is what a
gradient of that map needs.

Array names follow :mod:`ase_reversible.calculators.base`; each pair is
there once (``i < j``, or an image of one atom), and ``d_pc = x[j] - x[i]
+ image shift``.  Pair terms are summed onto atoms in pair order
(:meth:`ExactCalculator.scatter_pairs
<ase_reversible.calculators.base.ExactCalculator.scatter_pairs>`): with
pairs in a canonical order, the sums are reproducible bit for bit.  Powers
are products and dot products are summed in a fixed order
(:mod:`ase_reversible.core.portable`), so every result is the same bits on
every CPU, and a run can be continued or reversed on another machine.
"""

from __future__ import annotations

import numpy as np
from ase.calculators.calculator import all_changes
from ase.neighborlist import neighbor_list
from ase.stress import full_3x3_to_voigt_6_stress

from ..core.portable import outer_sum, rowdot, rowsquare, \
    rows_times_matrix
from .base import ExactCalculator


class LennardJones(ExactCalculator):
    """Smoothly cut-off Lennard-Jones pair potential, one species.

    Parameters
    ----------
    epsilon : float
        Depth of the pair potential well, eV.
    sigma : float
        Distance at which the (unswitched) pair energy is zero, Å.
    rc : float, optional
        Cut-off, Å: pairs further apart do not interact.  Default
        ``3 * sigma``.
    ro : float, optional
        Where the switch starts, Å (``0 <= ro < rc``).  Default
        ``0.66 * rc``.
    skin : float
        Å.  Pairs are searched within ``rc + skin`` and the search is
        repeated when an atom has moved more than ``skin / 2``.

    Besides ``energy``, ``energies``, ``forces`` and ``stress`` it offers
    :meth:`hessian_vector_product`, :meth:`force_parameter_derivative`
    and, for the reversible adjoint, both in one call:
    :meth:`~ase_reversible.calculators.base.ExactCalculator.vector_jacobian_product`.
    """

    implemented_properties = ['energy', 'free_energy', 'energies', 'forces',
                              'stress']
    default_parameters = {'epsilon': 1.0, 'sigma': 1.0, 'rc': None,
                          'ro': None, 'skin': 1.0}
    parameter_bounds = {'epsilon': 'positive', 'sigma': 'positive',
                        'rc': 'positive', 'ro': 'non-negative',
                        'skin': 'non-negative'}
    # Pairs through periodic images make the results depend on the cell.
    system_quantities = ('positions', 'numbers', 'cell', 'pbc')

    # Pure (see the base class): pair search results are reduced to the
    # pairs inside ``rc``, sorted, before any sum.

    #: Parameters the forces are differentiated by.
    differentiable_parameters = ('epsilon', 'sigma')

    def _forget(self):
        self._search = None   # (positions, cell, pbc, i_p, j_p, shift_pc)
        self._pairs = None    # (positions bytes, i_p, j_p, d_pc, r_p)

    @property
    def cutoffs(self):
        """``(ro, rc)`` in Å, defaults resolved."""
        p = self.parameters
        rc = 3.0 * p['sigma'] if p['rc'] is None else float(p['rc'])
        ro = 0.66 * rc if p['ro'] is None else float(p['ro'])
        return ro, rc

    def _check_relations(self):
        ro, rc = self.cutoffs
        if not ro < rc:
            raise ValueError(f'Need 0 <= ro < rc, got ro={ro!r}, rc={rc!r} '
                             '(Å)')

    # -- ASE calculator interface ---------------------------------------

    def calculate(self, atoms=None, properties=('energy',),
                  system_changes=all_changes):
        """ASE's calculator hook: fills ``self.results``.

        ``energy`` and ``free_energy`` (eV), ``energies`` ``[n_atoms]``
        (eV, each pair split equally), ``forces`` ``[n_atoms, 3]`` (eV/Å),
        and ``stress`` (Voigt 6, eV/Å³) only if asked for (needs a cell of
        three non-zero vectors).
        """
        super().calculate(atoms, properties, system_changes)
        n = len(self.atoms)
        i_p, j_p, d_pc, r_p = self._pair_geometry(self.atoms)
        u_p, du_p, _ = self._pair_terms(r_p, second=False)
        # Force on i from the pair: du/dr * d / r (d points from i to j).
        g_pc = (du_p / r_p)[:, None] * d_pc
        f_nc = self.scatter_pairs(g_pc, i_p, j_p, n)
        energies_n = self.split_pair_energies(u_p, i_p, j_p, n)
        self.store_results(float(np.sum(u_p)), energies_n, f_nc)
        if 'stress' in properties:  # only on request: MD never asks
            if self.atoms.cell.rank != 3:
                raise ValueError('Stress needs a cell with three non-zero '
                                 'vectors.')
            stress_cc = outer_sum(d_pc, g_pc) / self.atoms.get_volume()
            self.results['stress'] = full_3x3_to_voigt_6_stress(stress_cc)

    # -- derivatives ------------------------------------------------------

    def hessian_vector_product(self, atoms, v_nc):
        """``H v``: the Hessian of the energy times ``v``, eV/Å².

        ``v_nc`` is ``[n_atoms, 3]``, the result too.  ``H = -dF/dx`` is
        symmetric, so this is also ``-(dF/dx)^T v``, the product the
        adjoint of a kick needs.
        """
        v_nc = self.as_vector(atoms, v_nc)
        n = len(atoms)
        i_p, j_p, d_pc, r_p = self._pair_geometry(atoms)
        _, du_p, d2u_p = self._pair_terms(r_p, second=True)
        # The force on i from a pair is g(r) d with g = u'/r; its
        # derivative along d is g I + (g'/r) d d^T, with g' = u''/r - u'/r².
        g_p = du_p / r_p
        h_p = (d2u_p - g_p) / (r_p * r_p)
        dv_pc = v_nc[j_p] - v_nc[i_p]
        jv_pc = g_p[:, None] * dv_pc \
            + (h_p * rowdot(d_pc, dv_pc))[:, None] * d_pc
        # +jv on j, -jv on i: the indices swapped rather than the sum
        # negated, which would turn a zero sum into -0.0.
        return self.scatter_pairs(jv_pc, j_p, i_p, n)

    def _force_parameter_derivative(self, atoms, name):
        """``dF/d(name)`` ``[n_atoms, 3]``: Å⁻¹ for ``'epsilon'``, eV/Å²
        for ``'sigma'``.

        The derivative is that of the calculator the constructor would
        make with another ``sigma``: a cut-off left to its default
        (``rc = 3 sigma``, ``ro = 0.66 rc``) moves with ``sigma``, one
        given stays where it is.
        """
        n = len(atoms)
        i_p, j_p, d_pc, r_p = self._pair_geometry(atoms)
        epsilon, sigma = self.parameters['epsilon'], self.parameters['sigma']
        if name == 'epsilon':
            _, du_p, _ = self._pair_terms(r_p, second=False)
            ddu_p = du_p / epsilon
        else:
            s6_p, s12_p = _powers(sigma / r_p)
            phi_p = 4 * epsilon * (s12_p - s6_p)
            dphi_p = 4 * epsilon * (-12 * s12_p + 6 * s6_p) / r_p
            switch_p, dswitch_p, d2switch_p = self._switch(r_p)
            # d/dsigma of phi and of dphi/dr, at fixed r.
            phi_s_p = 4 * epsilon * (12 * s12_p - 6 * s6_p) / sigma
            dphi_s_p = 4 * epsilon * (-144 * s12_p + 36 * s6_p) / (
                r_p * sigma)
            ddu_p = dphi_s_p * switch_p + phi_s_p * dswitch_p
            dro, dwidth = self._cutoff_rates()
            if dwidth or dro:
                # The switch's t = (r - ro) / w moves with the cut-offs:
                # dt/dsigma = -(dro + t dw) / w, so dS/dsigma = -S'(r)
                # (dro + t dw) and d(S'(r))/dsigma = -S''(r) (dro + t dw)
                # - S'(r) dw / w, S' and S'' derivatives along r.
                ro, rc = self.cutoffs
                width = rc - ro
                t_p = np.clip((r_p - ro) / width, 0.0, 1.0)
                rate_p = dro + t_p * dwidth
                ddu_p += -dphi_p * dswitch_p * rate_p - phi_p * (
                    d2switch_p * rate_p + dswitch_p * (dwidth / width))
        g_pc = (ddu_p / r_p)[:, None] * d_pc
        return self.scatter_pairs(g_pc, i_p, j_p, n)

    # -- pairs ------------------------------------------------------------

    def _cutoff_rates(self):
        """``(dro/dsigma, d(rc - ro)/dsigma)``: non-zero for the cut-offs
        left to their defaults, which follow ``sigma``."""
        p = self.parameters
        drc = 3.0 if p['rc'] is None else 0.0
        dro = 0.66 * drc if p['ro'] is None else 0.0
        return dro, drc - dro

    def _pair_terms(self, r_p, second):
        """``u``, ``du/dr`` and (if ``second``) ``d2u/dr2`` per pair."""
        epsilon, sigma = self.parameters['epsilon'], self.parameters['sigma']
        s6_p, s12_p = _powers(sigma / r_p)
        phi_p = 4 * epsilon * (s12_p - s6_p)
        dphi_p = 4 * epsilon * (-12 * s12_p + 6 * s6_p) / r_p
        switch_p, dswitch_p, d2switch_p = self._switch(r_p)
        u_p = phi_p * switch_p
        du_p = dphi_p * switch_p + phi_p * dswitch_p
        if not second:
            return u_p, du_p, None
        d2phi_p = 4 * epsilon * (156 * s12_p - 42 * s6_p) / (r_p * r_p)
        d2u_p = (d2phi_p * switch_p + 2 * dphi_p * dswitch_p
                 + phi_p * d2switch_p)
        return u_p, du_p, d2u_p

    def _switch(self, r_p):
        ro, rc = self.cutoffs
        width = rc - ro
        t_p = np.clip((r_p - ro) / width, 0.0, 1.0)
        t2_p = t_p * t_p
        u_p = 1 - t_p
        switch_p = 1 - t2_p * t_p * (10 - 15 * t_p + 6 * t2_p)
        dswitch_p = -30 * t2_p * (u_p * u_p) / width
        d2switch_p = -60 * t_p * u_p * (1 - 2 * t_p) / (width * width)
        return switch_p, dswitch_p, d2switch_p

    def _pair_geometry(self, atoms):
        """Pairs within ``rc`` at the atoms' positions, in canonical order.

        Cached for the last positions: the adjoint asks for the forces and
        then for Hessian-vector products at the same positions.
        """
        x_nc = atoms.positions
        key = x_nc.tobytes()
        if self._pairs is not None and self._pairs[0] == key:
            return self._pairs[1:]
        i_p, j_p, shift_pc = self._candidates(atoms)
        d_pc = x_nc[j_p] - x_nc[i_p] + shift_pc
        r_p = np.sqrt(rowsquare(d_pc))
        # Only pairs inside rc enter the sums, so the candidates' history
        # (where the search last ran) cannot change a single bit.
        inside_p = r_p < self.cutoffs[1]
        geometry = (i_p[inside_p], j_p[inside_p], d_pc[inside_p],
                    r_p[inside_p])
        self._pairs = (key,) + geometry
        return geometry

    def _candidates(self, atoms):
        """Pairs within ``rc + skin`` of where the search last ran."""
        x_nc, cell, pbc = atoms.positions, atoms.cell.array, atoms.pbc
        search = self._search
        skin = self.parameters['skin']
        if (search is not None and np.array_equal(search[1], cell)
                and np.array_equal(search[2], pbc)
                and len(search[0]) == len(x_nc)):
            moved_n = rowsquare(x_nc - search[0])
            if moved_n.max(initial=0.0) <= 0.25 * skin * skin:
                return search[3:]
        i_p, j_p, s_pc = neighbor_list('ijS', atoms,
                                       self.cutoffs[1] + skin)
        # Keep each pair once; order them canonically (by i, j, image).
        keep_p = (i_p < j_p) | ((i_p == j_p) & _positive_image(s_pc))
        order_p = np.lexsort((s_pc[keep_p, 2], s_pc[keep_p, 1],
                              s_pc[keep_p, 0], j_p[keep_p], i_p[keep_p]))
        i_p, j_p = i_p[keep_p][order_p], j_p[keep_p][order_p]
        shift_pc = rows_times_matrix(s_pc[keep_p][order_p], cell)
        self._search = (x_nc.copy(), cell.copy(), pbc.copy(), i_p, j_p,
                        shift_pc)
        return i_p, j_p, shift_pc


def _positive_image(s_pc):
    """True for the one of an image pair (i, i, S), (i, i, -S) to keep."""
    first_p = np.where(s_pc[:, 0] != 0, s_pc[:, 0],
                       np.where(s_pc[:, 1] != 0, s_pc[:, 1], s_pc[:, 2]))
    return first_p > 0


def _powers(s_p):
    """``(s**6, s**12)`` as products: ``**`` on arrays calls numpy's
    power, whose last bits depend on the CPU."""
    s2_p = s_p * s_p
    s6_p = s2_p * s2_p * s2_p
    return s6_p, s6_p * s6_p
