"""Constraints applied exactly: projections of every increment.

A constraint keeps reversal exact when it acts on each sub-step's increment
as a map ``P`` with ``P(-y) == -P(y)`` bitwise: the drift then adds
``P(rint(h p / m))``, a function of the momenta only, and the kick adds
``P(rint(h F(x)))``, a function of the positions only.  FixAtoms and
FixCartesian zero components, so constrained coordinates never change, not
even by a quantum.  FixedPlane and FixedLine project onto a plane or line;
as their directions are rarely grid-aligned, rounding lets atoms leave the
plane or line by a few quanta (a random walk of ~1e-12 Å per step).

FixCom is held on the integers, after rounding (:class:`FixedCentre`): the
momentum counts of every increment are made to sum to exactly zero in each
Cartesian component, so the total momentum is exactly zero at every step;
with equal masses the position increments are balanced the same way, so
the sum of the position counts -- the centre of mass -- never changes.

Hookean adds a restoring force instead: ASE's ``atoms.get_forces(md=True)``,
the call every force provider makes, adds the force of each constraint that
has a potential energy (``adjust_potential_energy``) to the calculator's
forces.  Hookean's force is a numpy function of ``atoms.positions`` alone
(the exact grid positions the atoms show), deterministic for the same inputs
on one machine, so the kick stays ``P(rint(h F(x)))`` with ``F`` the sum,
rounded once; it is left out of the projection.  ``get_potential_energy``
adds Hookean's energy the same way, so the energy check sees it once.  The
calculator's products for the adjoint leave it out, so the kick's adjoint
adds :func:`added_force_product`.

Constraints that move atoms by a float correction (FixBondLengths,
FixInternals, ...) would add an increment that is not a function of the
other variable, so they are refused; FixBondLengths and FixLinearTriatomic
are read as rigid bodies instead by the dynamics that runs them
(:mod:`ase_reversible.md.rigid`).
"""

from __future__ import annotations

import numpy as np
from ase.constraints import (FixAtoms, FixCartesian, FixCom, FixedLine,
                             FixedPlane, Hookean)
from ase.geometry import find_mic

from ..errors import UnsupportedConstraintError
from .rigid.layout import RIGID_CONSTRAINTS

#: Constraints that add a force of the positions (and its energy) through
#: ``atoms.get_forces(md=True)`` and ``get_potential_energy``: no projection.
ADDED_FORCES = (Hookean,)
SUPPORTED = (FixAtoms, FixCartesian, FixedPlane, FixedLine, FixCom) + \
    ADDED_FORCES


def no_projection(y_nc):
    """The projection without constraints: leaves ``y_nc`` as it is."""
    return None


class FixedCentre:
    """FixCom on the integer counts: a deterministic, odd balance.

    :meth:`balance` removes the sum over atoms of an integer increment
    ``r_nc`` in each Cartesian component: ``rint(w_i S)`` from atom ``i``
    (``w_i = m_i / M`` over the atoms free in that component), and what
    that rounding leaves, ``|R| <= n / 2``, as one count each from the
    ``|R|`` first atoms in a fixed order (heaviest first, then by index).
    The result sums to exactly zero, depends on ``r_nc`` alone (so a kick
    stays a function of the positions, a drift of the momenta) and is odd:
    ``balance(-r) == -balance(r)`` bitwise, so ``-h`` undoes it.

    What is held exactly: the momentum counts of the free atoms sum to
    zero in each component (every kick, every thermostat step; the
    constructor removes a net momentum as ASE's FixCom does, on the
    grid).  The drift moves atom ``i`` by ``rint(h p_i / m_i / q_x)``;
    the mass-weighted sum of these is not an integer relation, so:

    * equal masses (in a component, over its free atoms): the drift's
      increments are balanced too, the position counts' sum never changes
      and the centre of mass is exactly fixed;
    * unequal masses: the exact increments ``h p_i / m_i`` have zero
      mass-weighted sum (the total momentum is zero), so each drift moves
      the centre of mass by its rounding only, at most half a position
      quantum.

    Parameters
    ----------
    masses_n : numpy.ndarray ``[n_atoms]``
        amu.
    free_nc : numpy.ndarray ``[n_atoms, 3]``
        Nonzero where the other constraints leave a coordinate free.
    """

    def __init__(self, masses_n, free_nc):
        free_nc = np.asarray(free_nc) != 0
        mass_nc = masses_n[:, None] * free_nc
        total_c = mass_nc.sum(axis=0)
        self.free_nc = free_nc
        self.weights_nc = np.divide(mass_nc, total_c,
                                    out=np.zeros_like(mass_nc),
                                    where=total_c > 0)
        self._largest_weight_c = self.weights_nc.max(axis=0).tolist()
        self._ones_n = np.ones(len(masses_n))
        self._weight_c = self.weights_nc.max(axis=0)
        self._uniform = bool(free_nc.all()) and bool(np.all(
            self.weights_nc == self._weight_c))
        # Per component: the free atoms, heaviest first, then by index; a
        # slice where that is the first atoms in order (the common case).
        self.order_c = [np.flatnonzero(free_nc[:, c])[
            np.argsort(-masses_n[free_nc[:, c]], kind='stable')]
            for c in range(3)]
        self._first_c = [slice(None) if np.array_equal(
            order, np.arange(len(order))) else order
            for order in self.order_c]
        self.equal_masses = all(
            np.all(masses_n[free_nc[:, c]] == masses_n[self.order_c[c][0]])
            for c in range(3) if len(self.order_c[c]))

    @property
    def components(self):
        """The Cartesian components with a free coordinate (each removes
        one degree of freedom)."""
        return sum(1 for order in self.order_c if len(order))

    def balance(self, r_nc):
        """Make the integer-valued float array ``r_nc`` ``[n_atoms, 3]``
        sum to exactly zero in each component, in place."""
        # Sums of whole numbers below 2**53 are exact in any order, so a
        # matrix-vector product (the fastest sum over axis 0 of [n, 3])
        # gives the same bits on every machine.
        sum_c = np.dot(self._ones_n, r_nc)
        left_c = sum_c.tolist()
        if not any(left_c):
            return
        if any(abs(total) * weight > 0.5 for total, weight in
               zip(left_c, self._largest_weight_c)):
            if self._uniform:
                # Every w_i is the same number: one share per component.
                share_c = np.rint(sum_c * self._weight_c)
                r_nc -= share_c
                left_c = (sum_c - len(r_nc) * share_c).tolist()
            else:
                share_nc = self.weights_nc * sum_c
                np.rint(share_nc, out=share_nc)
                r_nc -= share_nc
                left_c = (sum_c - np.dot(self._ones_n, share_nc)).tolist()
        # Otherwise every rint(w_i S) is 0: only the remainder, S, goes.
        for c, left in enumerate(left_c):
            if left:
                first = self._first_c[c]
                count = abs(int(left))
                rows = first[:count] if isinstance(first, np.ndarray) \
                    else slice(count)
                r_nc[rows, c] -= 1.0 if left > 0 else -1.0

    def balanced_counts(self, counts_nc):
        """int64 counts ``[n_atoms, 3]`` with their sum removed by
        :meth:`balance` (a new array): the grid's form of ASE's
        ``FixCom.adjust_momenta``."""
        r_nc = counts_nc.astype(np.float64)
        self.balance(r_nc)
        return r_nc.astype(np.int64)

    def pull_back(self, a_nc):
        """The adjoint of the kick's balance, in place: the balance is
        ``f_i - w_i sum_j f_j`` up to rounding, whose transpose is
        ``a_i - sum_j w_j a_j`` on the free coordinates."""
        a_nc -= self.free_nc * np.einsum('nc,nc->c', self.weights_nc, a_nc)


def _refuse(constraint, why):
    names = ', '.join(cls.__name__ for cls in SUPPORTED)
    raise UnsupportedConstraintError(
        f'{type(constraint).__name__} {why}. Supported constraints: '
        f'{names}. Remove it (del atoms.constraints) or use ASE\'s '
        'VelocityVerlet (not reversible) for this system.')


def constraint_projection(atoms, rigid=False):
    """In-place projection ``project(y_nc)`` for the atoms' constraints.

    ``rigid``: the dynamics runs rigid bodies, so FixBondLengths and
    FixLinearTriatomic are left to :func:`.rigid.layout.rigid_layout`.
    Returns a callable that projects an increment ``y_nc`` ``[n_atoms, 3]``
    (any unit) in place and returns None; its attribute ``centre`` is the
    :class:`FixedCentre` of a FixCom, or None.  Raises
    :class:`UnsupportedConstraintError` for constraints that are not
    projections.
    """
    constraints = list(atoms.constraints)
    if rigid:
        constraints = [c for c in constraints
                       if not isinstance(c, RIGID_CONSTRAINTS)]
    for c in constraints:
        if isinstance(c, RIGID_CONSTRAINTS):
            _refuse(c, 'makes molecules rigid: ReversibleVerlet runs them '
                    'exactly when the constraint is set before it is '
                    'constructed; other dynamics, and a constraint added in '
                    'mid-run, do not yet')
        if not isinstance(c, SUPPORTED):
            _refuse(c, 'cannot be applied exactly in fixed point and would '
                    'break exact reversal')
    centred = any(isinstance(c, FixCom) for c in constraints)
    constraints = [c for c in constraints
                   if not isinstance(c, (FixCom,) + ADDED_FORCES)]
    if centred:
        for c in constraints:
            if isinstance(c, (FixedPlane, FixedLine)):
                _refuse(c, 'together with FixCom is not supported: the '
                        'centre of mass is held per Cartesian component, '
                        'which a plane or line off the axes mixes. Use '
                        'FixCartesian if the plane or line is along the '
                        'axes, or zero the total momentum once '
                        '(ase.md.velocitydistribution.Stationary) instead '
                        'of FixCom')
    if not constraints and not centred:
        return no_projection

    def project(y_nc):
        for c in constraints:
            c.adjust_forces(atoms, y_nc)

    project.centre = None
    if centred:
        free_nc = np.ones((len(atoms), 3))
        project(free_nc)
        project.centre = FixedCentre(atoms.get_masses(), free_nc)
    return project


def added_force_product(atoms, w_nc):
    """``(dF/dx)^T w`` ``[n_atoms, 3]`` (eV/Å² x unit of ``w_nc``
    ``[n_atoms, 3]``) of the forces the atoms' Hookean constraints add at
    their positions, or None where no constraint adds a force: the part of
    the kick's adjoint that the calculator's product does not hold."""
    product_nc = None
    for c in atoms.constraints:
        if isinstance(c, Hookean):
            if product_nc is None:
                product_nc = np.zeros_like(w_nc)
            _hookean_product(c, atoms, w_nc, product_nc)
    return product_nc


def _hookean_product(spring, atoms, w_nc, out_nc):
    """Add the Hookean ``spring``'s ``(dF/dx)^T w`` to ``out_nc``.

    Its Hessian is symmetric.  Plane: ``F = -k d n`` above it, so ``-k n
    (n . w)``.  Bond and point: ``F_1 = g(r_vec)`` with ``r_vec`` from atom
    1 to atom 2 (or the point) beyond the threshold ``r_t``, ``dg/dr_vec =
    M = k (u u^T + (1 - r_t / r)(I - u u^T))``; ``r_vec`` moves against
    atom 1 and with atom 2 (whose force is ``-g``), so atom 1 gets ``M
    (w_2 - w_1)`` and atom 2 its negative (for a point, ``w_2 = 0``).
    """
    x_nc, k = atoms.positions, spring.spring
    if spring._type == 'plane':
        normal_c = np.asarray(spring.plane[:3], dtype=float)
        norm = np.linalg.norm(normal_c)
        i = spring.index
        if (normal_c @ x_nc[i] + spring.plane[3]) / norm < 0:
            return  # below the plane: no force (as adjust_forces)
        n_c = normal_c / norm
        out_nc[i] -= k * (n_c @ w_nc[i]) * n_c
        return
    if spring._type == 'two atoms':
        i, j = spring.indices
        r_c = x_nc[j] - x_nc[i]
        w_c = w_nc[j] - w_nc[i]
    else:
        i, j = spring.index, None
        r_c = spring.origin - x_nc[i]
        w_c = -w_nc[i]
    r_c, _ = find_mic(r_c, atoms.cell, atoms.pbc)
    r = np.linalg.norm(r_c)
    if not r > spring.threshold:
        return
    u_c = r_c / r
    along_c = (u_c @ w_c) * u_c
    mw_c = k * (along_c + (1.0 - spring.threshold / r) * (w_c - along_c))
    out_nc[i] += mw_c
    if j is not None:
        out_nc[j] -= mw_c
