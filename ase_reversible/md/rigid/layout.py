"""Which atoms form rigid bodies, their shapes, and the bodies' state
fitted to the atoms.

ASE makes a molecule rigid by constraints that move atoms by a float
correction (RATTLE), which cannot be undone exactly.  Here they are read
as a declaration of rigid bodies instead:

* ``FixBondLengths`` whose bonds join atoms in triangles of three bonds
  over three atoms (water: O-H, O-H, H-H) or single bonds over two atoms
  (a rigid diatomic) makes each group one body, with the bond lengths the
  constraint holds (given, or those at the first use, as ASE takes them);
* ``FixLinearTriatomic`` makes each triple ``(n, o, m)`` one linear body
  with the atoms' present distances ``n-o`` and ``o-m``, ``o`` between.

Every body of a system has the same number of atoms (2 or 3).
"""

from __future__ import annotations

import copy
import math

import numpy as np
from ase.constraints import FixBondLengths, FixLinearTriatomic
from ase.geometry import find_mic

from ...core import rigid
from ...errors import UnsupportedConstraintError

#: The constraints read as rigid bodies.
RIGID_CONSTRAINTS = (FixBondLengths, FixLinearTriatomic)

_WHAT_TO_DO = (
    'Rigid molecules are run exactly by ReversibleVerlet when every '
    'FixBondLengths group is a triangle of three bonds over three atoms '
    '(water) or one bond over two atoms, or by FixLinearTriatomic, with no '
    'other constraint. Otherwise use ASE\'s VelocityVerlet (not '
    'reversible) for this system.')


def refuse(why):
    """Raise UnsupportedConstraintError: ``why``, and what to do."""
    raise UnsupportedConstraintError(f'{why}. {_WHAT_TO_DO}')


class RigidLayout:
    """The rigid bodies of a system of atoms and their shapes.

    Attributes
    ----------
    bodies_bx : int array ``[b, x]``
        The atoms of each body (``x`` = 2 or 3 atoms).
    free_f : int array ``[f]``
        The atoms in no body, ascending.
    linear_b : bool array ``[b]``
        Bodies whose atoms lie on a line (axis 0 of their frame, moment 0).
    masses_b : float array ``[b]``
        amu.
    moments_bc : float array ``[b, 3]``
        Principal moments of inertia, amu Å**2 (0 about a linear body's
        line).
    body_bxc : float array ``[b, x, 3]``
        Each atom's coordinates in its body's principal frame, Å.
    atom_masses_bx : float array ``[b, x]``
        amu.
    """

    def __init__(self, bodies_bx, n_atoms, masses_n, shapes_bxc):
        self.bodies_bx = np.asarray(bodies_bx, dtype=int)
        in_body = np.zeros(n_atoms, dtype=bool)
        in_body[self.bodies_bx.ravel()] = True
        self.free_f = np.flatnonzero(~in_body)
        self.atom_masses_bx = masses_n[self.bodies_bx]
        self.masses_b = self.atom_masses_bx.sum(axis=1)
        #: ``[n_sites]`` amu: the free atoms', then the bodies'.
        self.site_masses = np.concatenate([masses_n[self.free_f],
                                           self.masses_b])
        frames = [rigid.principal_frame(shape, m) for shape, m in
                  zip(shapes_bxc, self.atom_masses_bx)]
        self.moments_bc = np.array([f[1] for f in frames]).reshape(-1, 3)
        self.body_bxc = np.array([f[2] for f in frames]).reshape(
            self.bodies_bx.shape + (3,))
        self._set_moments()

    def _set_moments(self):
        self.linear_b = self.moments_bc[:, 0] == 0.0
        # 1 / I, 0 about a linear body's line (no turn about it).
        self.inverse_moments_bc = np.divide(
            1.0, self.moments_bc, out=np.zeros_like(self.moments_bc),
            where=self.moments_bc > 0.0)

    def with_shapes(self, body_bxc, moments_bc):
        """This layout with the shapes ``body_bxc`` ``[b, x, 3]`` (Å) and
        moments ``moments_bc`` ``[b, 3]`` (amu Å**2) of a restart record:
        bit for bit those of the run that wrote it, wherever it ran.
        Raises ValueError if they are not this layout's shapes (the
        constraint now holds other lengths)."""
        if body_bxc.shape != self.body_bxc.shape \
                or moments_bc.shape != self.moments_bc.shape:
            raise ValueError('the record holds other shapes')
        # The same distances within each body, to the rounding of the
        # frames (another machine's eigenvectors differ in last bits).
        if not np.allclose(_distances(body_bxc), _distances(self.body_bxc),
                           rtol=1e-12, atol=1e-12):
            raise ValueError('the record holds other shapes')
        new = copy.copy(self)
        new.body_bxc, new.moments_bc = body_bxc, moments_bc
        new._set_moments()
        return new

    @property
    def n_bodies(self):
        """The number of bodies."""
        return len(self.bodies_bx)

    @property
    def n_sites(self):
        """Free atoms and bodies: what has a position and momentum."""
        return len(self.free_f) + self.n_bodies

    def fit(self, atoms):
        """The bodies' state fitted to the atoms: ``(centres [b, 3] Å,
        orientations [b, 4], momenta [b, 3], angular momenta [b, 3] in the
        body frame, amu Å**2 / ASE time unit)``.

        Each body is laid onto its atoms (mic-unwrapped from its first
        atom) by mass-weighted least squares; its momentum and angular
        momentum are those of its atoms' momenta (their rigid part).
        """
        x_nc = atoms.positions
        p_nc = atoms.get_momenta()
        centres, quats, momenta, spins = [], [], [], []
        for atoms_x, m_x, body_xc in zip(self.bodies_bx, self.atom_masses_bx,
                                         self.body_bxc):
            r_xc = unwrapped(x_nc[atoms_x], atoms.cell, atoms.pbc)
            centre = (m_x[:, None] * r_xc).sum(axis=0) / m_x.sum()
            a = rigid.kabsch(body_xc, r_xc - centre, m_x)
            rel_xc = body_xc @ a.T
            p_xc = p_nc[atoms_x]
            centres.append(centre)
            quats.append(rigid.quaternion_of(a))
            momenta.append(p_xc.sum(axis=0))
            spins.append(a.T @ np.cross(rel_xc, p_xc).sum(axis=0))
        spins = np.array(spins).reshape(-1, 3)
        spins[self.linear_b, 0] = 0.0  # no spin about the line
        return (np.array(centres).reshape(-1, 3),
                np.array(quats).reshape(-1, 4),
                np.array(momenta).reshape(-1, 3), spins)


def _distances(body_bxc):
    """``[b, x, x]``: the distances between each body's atoms, Å."""
    d = body_bxc[:, :, None, :] - body_bxc[:, None, :, :]
    return np.sqrt((d * d).sum(axis=-1))


def unwrapped(r_xc, cell, pbc):
    """A molecule's positions ``[x, 3]`` with each atom at the minimum
    image from the first."""
    d_xc, _ = find_mic(r_xc - r_xc[0], cell, pbc)
    return r_xc[0] + d_xc


def refuse_guarded_rigid(purity, calc):
    """Refuse rigid bodies under the guarded force purity, whose guard
    bounds the rounding of each atom's kick, not of a body's sum and
    torque."""
    if purity.mode == 'guarded':
        raise UnsupportedConstraintError(
            'Rigid molecules are not run with the guarded force purity yet '
            f'({type(calc).__name__} needs it): its guard bounds the '
            "rounding of each atom's kick, not of a body's force and torque. "
            "Pass force_purity='cold-start' if the calculator allows, or "
            "use ASE's VelocityVerlet (not reversible).")


def rigid_layout(atoms, masses_n):
    """The :class:`RigidLayout` the atoms' constraints declare, or None if
    they declare no rigid body.  Raises
    :class:`~ase_reversible.UnsupportedConstraintError` for constraints
    that are neither rigid bodies nor absent."""
    constraints = list(atoms.constraints)
    rigid_ones = [c for c in constraints if isinstance(c, RIGID_CONSTRAINTS)]
    if not rigid_ones:
        return None
    others = [type(c).__name__ for c in constraints
              if not isinstance(c, RIGID_CONSTRAINTS)]
    if others:
        refuse(f'{", ".join(others)} together with rigid molecules is not '
               'supported')
    bodies, shapes = [], []
    for c in rigid_ones:
        if isinstance(c, FixBondLengths):
            b, s = _bond_bodies(atoms, c)
        else:
            b, s = _linear_bodies(atoms, c)
        bodies += b
        shapes += s
    sizes = {len(b) for b in bodies}
    if len(sizes) > 1:
        refuse('The rigid molecules have different numbers of atoms '
               f'({sorted(sizes)})')
    order = sorted(range(len(bodies)), key=lambda k: min(bodies[k]))
    bodies = [bodies[k] for k in order]
    shapes = [shapes[k] for k in order]
    flat = np.concatenate(bodies)
    if len(np.unique(flat)) != len(flat):
        refuse('An atom belongs to two rigid constraints')
    return RigidLayout(bodies, len(atoms), masses_n, np.array(shapes))


def _bond_bodies(atoms, constraint):
    pairs = np.asarray(constraint.pairs, dtype=int).reshape(-1, 2) \
        % len(atoms)
    lengths = constraint.bondlengths
    if lengths is None:
        lengths = constraint.initialize_bond_lengths(atoms)
        # As ASE would at the first use: the lengths held from now on.
        constraint.bondlengths = lengths
    lengths = np.asarray(lengths, dtype=float)
    groups = _connected(pairs)
    bodies, shapes = [], []
    for group in groups:
        members = sorted(group)
        inside = [k for k, (i, j) in enumerate(pairs) if i in group]
        if len(members) == 2 and len(inside) == 1:
            d = lengths[inside[0]]
            shapes.append([[0.0, 0.0, 0.0], [d, 0.0, 0.0]])
        elif len(members) == 3 and len(inside) == 3:
            shapes.append(_triangle(members, pairs[inside], lengths[inside]))
        else:
            refuse(f'FixBondLengths joins atoms {members} by {len(inside)} '
                   'bonds: not a rigid body (a triangle of three bonds or a '
                   'single bond); a chain of bonds leaves angles free, which '
                   'only a float correction (RATTLE) holds')
        bodies.append(members)
    return bodies, shapes


def _connected(pairs):
    groups = []
    for i, j in pairs:
        hit = [g for g in groups if i in g or j in g]
        merged = {int(i), int(j)}.union(*hit)
        groups = [g for g in groups if g not in hit] + [merged]
    return groups


def _triangle(members, pairs, lengths):
    """Coordinates ``[3, 3]`` of three atoms with the given distances."""
    d = {frozenset(map(int, p)): float(length)
         for p, length in zip(pairs, lengths)}
    a, b, c = members
    ab, ac, bc = d[frozenset((a, b))], d[frozenset((a, c))], \
        d[frozenset((b, c))]
    x = (ab * ab + ac * ac - bc * bc) / (2.0 * ab)
    y2 = ac * ac - x * x
    if not y2 >= 0.0 or not ab > 0.0:
        refuse(f'FixBondLengths holds atoms {members} at distances that '
               'make no triangle')
    return [[0.0, 0.0, 0.0], [ab, 0.0, 0.0], [x, math.sqrt(y2), 0.0]]


def _linear_bodies(atoms, constraint):
    triples = np.asarray(constraint.triples, dtype=int).reshape(-1, 3) \
        % len(atoms)
    bodies, shapes = [], []
    for n, o, m in triples:
        r_xc = unwrapped(atoms.positions[[n, o, m]], atoms.cell, atoms.pbc)
        d_no = float(np.linalg.norm(r_xc[1] - r_xc[0]))
        d_om = float(np.linalg.norm(r_xc[2] - r_xc[1]))
        bodies.append([int(n), int(o), int(m)])
        shapes.append([[0.0, 0.0, 0.0], [d_no, 0.0, 0.0],
                       [d_no + d_om, 0.0, 0.0]])
    return bodies, shapes
