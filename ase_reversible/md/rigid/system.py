"""Atoms with rigid bodies as a Hamiltonian system in fixed point.

The exact variables are ``'position'`` and ``'momentum'`` of the *sites*
``[s, 3]`` -- the free atoms, then the bodies' centres of mass -- and each
body's ``'orientation'`` quaternion ``[b, 4]`` and ``'angular_momentum'``
in its principal frame ``[b, 3]`` (:mod:`ase_reversible.core.rigid`).
The atoms show the free atoms' values and each body's atoms at ``X + A(q)
d`` with the momenta of its rigid motion, ``m (V + omega x A d)``.

The two sub-steps are the Hamiltonian's, for bodies:

* drift: the sites' ``x += round_odd(c h p / m / q_x)``, and the free
  rotation of every body (:class:`RigidDrift`), both functions of the
  momenta only;
* kick: the sites' ``p += round_odd(c h F / q_p)`` with a body's force the
  sum of its atoms', and ``L += round_odd(c h tau / q_L)`` with the torque
  in the body frame, both functions of the positions and orientations
  only (:class:`RigidKick`).
"""

from __future__ import annotations

import numpy as np
from ase import units

from ...core import rigid
from ...core.codec import encode, round_odd
from ...core.plans import SubStep
from ...core.quanta import (Grid, choose_angular_momentum_quantum,
                            choose_grid)
from ...core.variables import ExactVariable
from ...errors import QuantumRangeError, UnstableIntegrationError
from ..constraints import no_projection
from ..hamiltonian import Hamiltonian, non_finite_forces
from .adjoint import drift_pullback, kick_pullback

#: The restart record's section of rigid bodies: their atoms, shapes and
#: the counts of the four variables (the atoms show none of a body's).
SECTION = 'rigid'
#: The variables of a rigid system, by name.
VARIABLES = ('position', 'momentum', 'orientation', 'angular_momentum')

#: The free rotation of an asymmetric body: ``(axis, fraction of c h)``, a
#: palindrome (Dullweber, Leimkuhler and McLachlan's splitting), the axis
#: of the largest moment in the middle.
ROTATION_SPLIT = ((0, 0.5), (1, 0.5), (2, 1.0), (1, 0.5), (0, 0.5))


def rigid_values(atoms, layout):
    """The four variables' float values by name for the atoms, the bodies
    fitted to them by
    :meth:`~ase_reversible.md.rigid.layout.RigidLayout.fit`."""
    centres, quats, momenta, spins = layout.fit(atoms)
    free = layout.free_f
    return {'position': np.concatenate([atoms.positions[free], centres]),
            'momentum': np.concatenate([atoms.get_momenta()[free],
                                        momenta]),
            'orientation': quats, 'angular_momentum': spins}


def rigid_counts(values, grid, angular_quantum):
    """The int64 counts of :func:`rigid_values`' ``values`` on ``grid``
    and the angular momentum quantum ``angular_quantum``."""
    quanta = {'position': grid.position_quantum,
              'momentum': grid.momentum_quantum,
              'orientation': rigid.ORIENTATION_QUANTUM,
              'angular_momentum': angular_quantum}
    return {name: encode(values[name], q, name.replace('_', ' '))
            for name, q in quanta.items()}


def resumed_system(atoms, layout, masses_n, purity, record):
    """The :class:`RigidSystem` of a frame's restart ``record`` (read with
    :data:`VARIABLES` and the :data:`SECTION`), or None where the record
    is not of these bodies or the atoms are not its state bit for bit
    (an edited frame: a new start)."""
    section = record.get(SECTION)
    try:
        if section is None or not np.array_equal(
                np.asarray(section['bodies']), layout.bodies_bx):
            return None
        layout = layout.with_shapes(np.asarray(section['body'], dtype=float),
                                    np.asarray(section['moments'],
                                               dtype=float))
        counts = {name: np.asarray(section[name], dtype=np.int64)
                  for name in VARIABLES}
    except (KeyError, TypeError, ValueError, OverflowError):
        return None
    grid = Grid(record['position_quantum'], record['momentum_quantum'])
    try:
        system = RigidSystem(atoms, grid, counts, masses_n, layout, purity,
                             record['angular_momentum_quantum'])
    except ValueError:
        return None
    momenta = atoms.arrays.get('momenta')
    if not (np.array_equal(system.shown_positions(), atoms.positions)
            and momenta is not None
            and np.array_equal(system.shown_momenta(), momenta)):
        return None
    return system


def rigid_system(atoms, layout, masses_n, purity, position_quantum=None,
                 momentum_quantum=None):
    """The :class:`RigidSystem` of the atoms and their ``layout``, on a
    grid chosen for its sites (quanta given, or the defaults)."""
    values = rigid_values(atoms, layout)
    # The extent: the atoms and the centres (a body's may lie outside).
    grid, _ = choose_grid(
        np.concatenate([atoms.positions, values['position']]), atoms.cell,
        atoms.pbc, layout.site_masses, values['momentum'],
        position_quantum=position_quantum, momentum_quantum=momentum_quantum)
    angular = choose_angular_momentum_quantum(layout.moments_bc,
                                              values['angular_momentum'])
    counts = rigid_counts(values, grid, angular)
    return RigidSystem(atoms, grid, counts, masses_n, layout, purity,
                       angular)


class RigidSystem(Hamiltonian):
    """Free atoms and rigid bodies as exact variables, and their forces.

    Parameters
    ----------
    atoms : ase.Atoms
        Shows the exact values (positions after every drift).
    grid : Grid
        The sites' two quanta.
    counts : dict
        int64 counts of the four variables (:func:`rigid_counts`).
    masses_n : numpy.ndarray ``[n_atoms]``
        amu.
    layout : RigidLayout
        The bodies.
    purity : force provider
    angular_quantum : float
        Quantum of the angular momentum, amu Å**2 / ASE time unit.
    """


    def __init__(self, atoms, grid, counts, masses_n, layout, purity,
                 angular_quantum):
        self.atoms = atoms
        self.grid = grid
        self.layout = layout
        self._atom_masses_n1 = masses_n[:, None]
        self.x = ExactVariable('position', counts['position'],
                               grid.position_quantum)
        self.p = ExactVariable('momentum', counts['momentum'],
                               grid.momentum_quantum)
        self.q = ExactVariable('orientation', counts['orientation'],
                               rigid.ORIENTATION_QUANTUM)
        self.l = ExactVariable('angular_momentum',
                               counts['angular_momentum'], angular_quantum)
        self.variables = {'position': self.x, 'momentum': self.p,
                          'orientation': self.q,
                          'angular_momentum': self.l}
        self.set_dynamics(layout.site_masses, no_projection, purity)
        self._inverse_moments_k = layout.inverse_moments_bc.reshape(-1)
        self._frame = (None, None, None)
        self._shown = (None, None)
        self._shapes = None
        self.drift = RigidDrift(self)
        self.kick = RigidKick(self)

    # -- what the atoms show ---------------------------------------------

    def frame(self):
        """``(A [b, 3, 3], A d [b, x, 3])``: the bodies' rotations and
        their atoms' positions relative to the centres, Å (cached for the
        present orientations)."""
        label, a, rel = self._frame
        if label != self.q.label:
            a = rigid.rotation_matrices(self.q.floats)
            rel = rigid.apply_rotations(a, self.layout.body_bxc)
            self._frame = (self.q.label, a, rel)
        return a, rel

    @property
    def atom_masses_n1(self):
        return self._atom_masses_n1

    def thermal_parts(self):
        """The angular momenta, with the principal moments (amu Å**2) as
        their masses: the thermostats act on them as on the momenta."""
        return ((self.l, self.layout.moments_bc.reshape(-1)),)

    def record_section(self):
        """The restart record's :data:`SECTION`: the bodies' atoms and
        shapes, and the counts of every variable (JSON-ready lists)."""
        if self._shapes is None:  # fixed for the system's life
            layout = self.layout
            self._shapes = {'bodies': layout.bodies_bx.tolist(),
                            'body': layout.body_bxc.tolist(),
                            'moments': layout.moments_bc.tolist()}
        return {**self._shapes,
                **{name: v.counts.astype(np.int64).tolist()
                   for name, v in self.variables.items()}}

    def encode(self, atoms, project):
        """The counts of the four variables fitted to the atoms
        (:func:`rigid_counts`); ``project`` is not used."""
        return rigid_counts(rigid_values(atoms, self.layout), self.grid,
                            self.l.quantum)

    def shown_positions(self, out=None):
        """The atoms' positions ``[n_atoms, 3]``, Å: the free atoms' counts'
        image and ``X + A d`` of the bodies' atoms (into ``out``, or a new
        array)."""
        layout = self.layout
        x = self.x.floats
        nf = len(layout.free_f)
        if out is None:
            out = np.empty((len(self.atoms), 3))
        out[layout.free_f] = x[:nf]
        out[layout.bodies_bx] = x[nf:, None, :] + self.frame()[1]
        return out

    def show_positions(self):
        self.shown_positions(out=self.atoms.arrays['positions'])

    def shown_momenta(self):
        """The atoms' momenta ``[n_atoms, 3]``: the free atoms' counts'
        image, and ``m (V + omega x A d)`` of the bodies' atoms."""
        key = (self.p.label, self.l.label, self.q.label)
        if self._shown[0] == key:
            return self._shown[1]
        layout = self.layout
        nf = len(layout.free_f)
        p = self.p.floats
        a, rel = self.frame()
        omega_bc = rigid.apply_rotations(
            a, (self.l.floats * layout.inverse_moments_bc)[:, None, :])
        v_bxc = (p[nf:] / layout.masses_b[:, None])[:, None, :] \
            + rigid.cross(omega_bc, rel)
        out = np.empty((len(self.atoms), 3))
        out[layout.free_f] = p[:nf]
        out[layout.bodies_bx] = layout.atom_masses_bx[:, :, None] * v_bxc
        self._shown = (key, out)
        return out

    def momentum_square(self):
        """``sum p^2 / m + sum L_k^2 / I_k`` (eV) of the exact counts'
        images: twice the kinetic energy, the same bits on every CPU."""
        v = self.p.floats / np.sqrt(self.m_n1)
        spin = self.l.floats.reshape(-1)
        return float(np.sum(v * v)) + float(
            np.sum(spin * spin * self._inverse_moments_k))

    # -- forces on the bodies --------------------------------------------

    def generalized_forces(self, f_nc):
        """``(F [s, 3] eV/Å, tau [b, 3] eV)``: the sites' forces (a body's
        the sum of its atoms') and the bodies' torques in their frames,
        from the atoms' forces ``f_nc``."""
        layout = self.layout
        nf = len(layout.free_f)
        a, rel = self.frame()
        f_bxc = f_nc[layout.bodies_bx]
        forces = np.empty((layout.n_sites, 3))
        forces[:nf] = f_nc[layout.free_f]
        forces[nf:] = rigid.atom_sum(f_bxc)
        torque = rigid.apply_transposed(
            a, rigid.atom_sum(rigid.cross(rel, f_bxc)))
        torque[layout.linear_b, 0] = 0.0  # a line has no spin about itself
        return forces, torque


def _explain_turn(angle, ch):
    return (f'A rigid molecule would turn by {angle:.3g} rad about one axis '
            f'in one sub-step (at most {rigid.MAX_TURN:g}): the time step '
            f'({abs(ch) / units.fs:g} fs for this sub-step) is too large for '
            'its rotation, or the run is blowing up. The step was not taken; '
            'the state is valid and reverse() leads back exactly. Use a '
            'smaller time step.')


class RigidDrift(SubStep):
    """The sites' ``x += round_odd(c h p / m / q_x)`` and the bodies' free
    rotation by ``c h``: functions of the momenta only; shown at once."""

    def __init__(self, system):
        self.system = system
        layout = system.layout
        #: The bodies turned about their three axes, and the linear ones.
        self.asymmetric = np.flatnonzero(~layout.linear_b)
        self.linear = np.flatnonzero(layout.linear_b)
        #: Radians per count of L_k and unit of c h, per axis of the
        #: asymmetric bodies.
        self.turn_bc = (system.l.quantum
                        * layout.inverse_moments_bc[self.asymmetric])
        self.split = ROTATION_SPLIT
        self._linear_moment = layout.moments_bc[self.linear, 1]

    def prepare(self, ch):
        s = self.system
        factor_n1 = ch / s.x.quantum / s.m_n1
        return ch, np.repeat(factor_n1 * s.p.quantum, 3, axis=1)

    def apply(self, prepared):
        ch, factor_nc = prepared
        s = self.system
        y_nc = np.multiply(s.p.counts, factor_nc)
        round_odd(y_nc, out=y_nc)
        s.x.add_integers(y_nc)
        try:
            self._turn(ch)
        except ValueError as turned:
            raise UnstableIntegrationError(
                _explain_turn(turned.args[0], ch)) from None
        s.show_positions()

    def _turn(self, ch):
        s = self.system
        q_bk = s.q.counts.copy()
        changed = False
        if len(self.asymmetric):
            rows = self.asymmetric
            q_ak, l_ak = q_bk[rows], s.l.counts[rows]
            for k, fraction in self.split:
                theta = l_ak[:, k] * self.turn_bc[:, k] * (fraction * ch)
                rigid.turn_about_axis(q_ak, l_ak, k, theta)
            q_bk[rows] = q_ak
            l_bk = s.l.counts.copy()
            l_bk[rows] = l_ak
            s.l.add_integers(l_bk - s.l.counts)
            changed = True
        if len(self.linear):
            rows = self.linear
            q_lk = q_bk[rows]
            rigid.turn_linear(q_lk, s.l.counts[rows], ch,
                              self._linear_moment, s.l.quantum)
            q_bk[rows] = q_lk
            changed = True
        if changed:
            s.q.add_integers(q_bk - s.q.counts)

    def last_move(self):
        """None: a record of rigid bodies digests no drift."""
        return None

    def adjoint(self, cotangents, ch):
        drift_pullback(self.system, self, cotangents, ch)

    def rollback(self):
        self.system.show_positions()


class RigidKick(SubStep):
    """``p += round_odd(c h F / q_p)`` on the sites and ``L +=
    round_odd(c h tau / q_L)`` on the bodies, the forces made pure."""

    def __init__(self, system):
        self.system = system
        self.forget()

    def forget(self):
        """Drop cached forces."""
        self._f_cache = self._saved = None
        self._r_key = self._r = None

    def prepare(self, ch):
        return ch

    def _positions_label(self):
        s = self.system
        return (s.x.label, s.q.label)

    def forces(self):
        """Forces ``[n_atoms, 3]`` (eV/Å) at the present positions."""
        label = self._positions_label()
        if self._f_cache is not None and self._f_cache[0] == label:
            return self._f_cache[1]
        s = self.system
        f_nc = s.purity.forces(s.atoms)
        self._f_cache = (label, f_nc)
        return f_nc

    def held(self, label=None):
        """``(forces, None)``: the forces at the present positions if
        computed (None otherwise); a rigid kick is digested by its
        forces."""
        f = self._f_cache
        here = label is None and f is not None \
            and f[0] == self._positions_label()
        return (f[1] if here else None), None

    def apply(self, ch):
        s = self.system
        key = (self._positions_label(), ch)
        if self._r_key != key:
            self._r_key = None
            forces, torque = s.generalized_forces(self.forces())
            self._r = (round_odd(forces * (ch / s.p.quantum)),
                       round_odd(torque * (ch / s.l.quantum)))
            self._r_key = key
        try:
            s.p.add_integers(self._r[0])
            s.l.add_integers(self._r[1])
        except QuantumRangeError:
            if not np.all(np.isfinite(self._f_cache[1])):
                raise non_finite_forces(s.atoms.calc) from None
            raise

    def adjoint(self, cotangents, ch):
        # Deferred: merged with the next kick at these positions.
        cotangents.defer(self._pull_back, ch)

    def _pull_back(self, cotangents, ch):
        kick_pullback(self.system, cotangents, ch)

    def checkpoint(self):
        self._saved = self._f_cache

    def rollback(self):
        self._f_cache = self._saved
        self._r_key = None
