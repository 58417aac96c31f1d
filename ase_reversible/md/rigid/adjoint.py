"""The adjoint rules of rigid bodies: ``backpropagate`` through their
drift and kick, and the change of variables between the atoms' shown
positions and momenta and the bodies' exact variables.

Cotangents are ``dL/d(value)`` of the four variables of a
:class:`~.system.RigidSystem` (``'position'`` and ``'momentum'`` of the
sites, ``'orientation'``, ``'angular_momentum'``), the roundings taken as
the identity, as the atoms' kicks and drifts take theirs.  With ``A`` the
rotation of a body, ``d`` its atoms' body-frame coordinates and ``f`` their
forces:

* the shown atoms: ``r = X + A d`` and ``p = m (P / M + A (omega x d))``,
  ``omega = L / I``;
* the kick: ``P += c h sum f`` and ``L += c h sum d x (A^T f)``, so its
  pull-back asks the calculator for one product with the atoms' cotangent
  ``w = a_P + A (a_L x d)`` and adds the explicit dependence of the torque
  on ``A``;
* a turn about body axis ``k`` by ``theta = c h L_k / I_k``: two pairs of
  quaternion components turned by ``theta / 2`` and a pair of ``L``'s by
  ``theta``, each pulled back by the transposed rotation, and ``L_k``
  collecting ``dtheta/dL_k`` times the turns' derivatives; the turns are
  pulled back in reverse order, each at its own state, which undoing the
  exact turn on the counts recovers bit for bit.
"""

from __future__ import annotations

import numpy as np

from ...core import rigid


def _along(derivatives_bkcj, v_bxc, u_bxj):
    """``[b, 4]``: ``sum_x v . (dA/dq_k u)`` for each body and ``k``."""
    return np.einsum('bkcj,bxc,bxj->bk', derivatives_bkcj, v_bxc, u_bxj)


def shown_cotangents(system, ax_nc, ap_nc):
    """The cotangents of the four variables (a dict of new arrays) for a
    loss with gradients ``ax_nc`` and ``ap_nc`` ``[n_atoms, 3]`` (or None)
    on the atoms' shown positions and momenta."""
    layout = system.layout
    nf, free, bodies = len(layout.free_f), layout.free_f, layout.bodies_bx
    d_bxc = layout.body_bxc
    derivatives = rigid.rotation_derivatives(system.q.floats)
    a_x = np.zeros((layout.n_sites, 3))
    a_x[:nf] = ax_nc[free]
    ar_bxc = ax_nc[bodies]
    a_x[nf:] = ar_bxc.sum(axis=1)
    a_q = _along(derivatives, ar_bxc, d_bxc)
    a_p = np.zeros((layout.n_sites, 3))
    a_l = np.zeros((layout.n_bodies, 3))
    if ap_nc is not None:
        m_bx1 = layout.atom_masses_bx[:, :, None]
        a_p[:nf] = ap_nc[free]
        mp_bxc = m_bx1 * ap_nc[bodies]
        a_p[nf:] = mp_bxc.sum(axis=1) / layout.masses_b[:, None]
        a, _ = system.frame()
        # (A^T m a_p) of each atom: the body frame's view of its cotangent.
        body_bxc = np.einsum('bcj,bxc->bxj', a, mp_bxc)
        a_l = layout.inverse_moments_bc * rigid.cross(d_bxc,
                                                     body_bxc).sum(axis=1)
        omega_bc = system.l.floats * layout.inverse_moments_bc
        a_q = a_q + _along(derivatives, mp_bxc,
                           rigid.cross(omega_bc[:, None, :], d_bxc))
    return {'position': a_x, 'momentum': a_p, 'orientation': a_q,
            'angular_momentum': a_l}


def kick_pullback(system, cotangents, ch):
    """The rigid kick's adjoint at the present positions: ``a_X``,
    ``a_q`` and the parameters' gradients from ``a_P``, ``a_L`` with
    coefficient ``ch``; one product of the forces' Jacobian."""
    layout = system.layout
    nf, free, bodies = len(layout.free_f), layout.free_f, layout.bodies_bx
    d_bxc = layout.body_bxc
    a_p = cotangents['momentum']
    a_l = np.array(cotangents['angular_momentum'])
    a_l[layout.linear_b, 0] = 0.0  # the kick zeroes that torque
    a, _ = system.frame()
    u_bxc = rigid.cross(a_l[:, None, :], d_bxc)
    w_nc = np.zeros((len(system.atoms), 3))
    w_nc[free] = a_p[:nf]
    w_nc[bodies] = a_p[nf:, None, :] + rigid.apply_rotations(a, u_bxc)
    if not w_nc.any():
        return
    dx_nc, dtheta = cotangents.product(system.atoms, w_nc)
    cotangents.products += 1
    g_nc = ch * np.asarray(dx_nc)
    cotangents['position'][:nf] += g_nc[free]
    g_bxc = g_nc[bodies]
    cotangents['position'][nf:] += g_bxc.sum(axis=1)
    derivatives = rigid.rotation_derivatives(system.q.floats)
    f_bxc = system.kick.forces()[bodies]
    cotangents['orientation'] += _along(derivatives, g_bxc, d_bxc) \
        + ch * _along(derivatives, f_bxc, u_bxc)
    grads = cotangents.grad_parameters
    for name in grads:
        grads[name] = grads[name] + ch * np.asarray(dtheta[name],
                                                    dtype=float)


def _pull_pair(values, cotangent, i, j, angle):
    """Pull ``cotangent`` back through the turn by ``angle`` ``[b]`` of the
    pair ``(i, j)`` of ``values`` (after the turn; rows by body), in place;
    returns ``a' . d(values')/d(angle)``."""
    u, v = values[:, i], values[:, j]
    au, av = cotangent[:, i].copy(), cotangent[:, j].copy()
    c, s = np.cos(angle), np.sin(angle)
    cotangent[:, i] = c * au + s * av
    cotangent[:, j] = -s * au + c * av
    return -au * v + av * u


def drift_pullback(system, drift, cotangents, ch):
    """The rigid drift's adjoint with coefficient ``ch``, at the state
    after it: the translation's ``a_P += c h a_X / M``, then the bodies'
    turns in reverse order."""
    cotangents.flush()
    cotangents['momentum'] += ch * cotangents['position'] / system.m_n1
    layout = system.layout
    a_q, a_l = cotangents['orientation'], cotangents['angular_momentum']
    rows = drift.asymmetric
    if len(rows):
        q_counts = system.q.counts[rows]
        l_counts = system.l.counts[rows]
        aq, al = a_q[rows], a_l[rows]
        inverse = layout.inverse_moments_bc[rows]
        for k, fraction in reversed(drift.split):
            theta = l_counts[:, k] * drift.turn_bc[:, k] * (fraction * ch)
            q = q_counts * system.q.quantum
            spin = l_counts * system.l.quantum
            slope = np.zeros(len(rows))
            for i, j in rigid.QUATERNION_PAIRS[k]:
                slope += 0.5 * _pull_pair(q, aq, i, j, 0.5 * theta)
            slope += _pull_pair(spin, al, *rigid.MOMENTUM_PAIRS[k], theta)
            al[:, k] += inverse[:, k] * (fraction * ch) * slope
            rigid.turn_about_axis(q_counts, l_counts, k, -theta)
        a_q[rows], a_l[rows] = aq, al
    rows = drift.linear
    if len(rows):
        moment = layout.moments_bc[rows, 1]
        spin = system.l.floats[rows]
        q_after = system.q.floats[rows]
        phi = (ch / moment)[:, None] * spin
        turn = rigid.rotation_quaternion(phi)
        conjugate = turn * np.array([1.0, -1.0, -1.0, -1.0])
        q_before = rigid.quaternion_product(q_after, conjugate)
        aq = a_q[rows]
        step = 1e-30
        for i in (1, 2):
            shifted = phi.astype(complex)
            shifted[:, i] += 1j * step
            dq = rigid.quaternion_product(
                q_before, rigid.rotation_quaternion(shifted)).imag / step
            a_l[rows, i] += (ch / moment) * (aq * dq).sum(axis=1)
        a_q[rows] = rigid.quaternion_product(aq, conjugate)
