"""Rigid bodies in fixed point: orientations turned by rounded shears.

A rigid body is its centre of mass and momentum (kept with the free
atoms' positions and momenta), an orientation quaternion ``q`` and its
angular momentum ``L`` in the body's principal frame, all whole numbers
of power-of-two quanta.  Its atoms sit at ``X + A(q) d`` with ``d`` the
body-frame coordinates and ``A(q)`` the rotation of ``q / |q|``: the
quaternion's length does not enter, so its random walk by rounding never
moves an atom, and no re-projection (which would break reversal) is
needed.

The free rotation ``H = sum_k L_k**2 / (2 I_k)`` is split into rotations
about the principal axes (Dullweber, Leimkuhler and McLachlan, J. Chem.
Phys. 107, 5840 (1997); Miller et al., J. Chem. Phys. 116, 8649 (2002)):
the flow of ``L_k**2 / (2 I_k)`` turns the body about its axis ``k`` by
``theta = c h L_k / I_k`` and leaves ``L_k`` unchanged, so the angle is a
function of a value the rotation does not change.  The rotation turns two
pairs of quaternion components by ``theta / 2`` and the pair of ``L``'s
other components by ``theta``; each plane rotation is three rounded shears
(Paeth's rotation by shears)::

    u += round_odd(a v);  v += round_odd(b u);  u += round_odd(a v)

with ``a = -tan(phi / 2)`` and ``b = sin(phi)``, each undone exactly by the
same shear with ``-a`` or ``-b``, and the three in reverse order are the
same three.  ``-theta`` gives ``-a`` and ``-b`` bitwise (the functions
below are odd by construction), so the rotation by ``-theta`` is the exact
inverse.  ``tan`` comes from Lambert's continued fraction in ``+ - * /``
only, ``sin`` from ``tan`` (``2 t / (1 + t**2)``): the same bits on every
CPU, and a plane rotation by exactly ``2 atan(t)`` up to the rounding of
``a`` and ``b``.

A linear body (its atoms on a line, one principal moment zero) turns
about the axis along its angular momentum, which is perpendicular to the
line and unchanged by the free rotation: the rotation is written as three
rotations about body axes (:func:`turn_linear`), their angles functions of
``L`` alone.

Shapes: ``[b]`` per body, ``[b, 4]`` quaternions ``(w, x, y, z)``,
``[b, 3]`` vectors, ``[b, 3, 3]`` rotations, ``[b, a, 3]`` the
body-frame coordinates of each body's ``a`` atoms.
"""

from __future__ import annotations

import math

import numpy as np

from .codec import round_odd

#: Quantum of the orientation quaternion's components (whose magnitudes
#: stay near 1): 2**-50 leaves three bits of range, and rounding moves the
#: orientation by ~1e-15 rad a shear.
ORIENTATION_QUANTUM = 2.0**-50

#: Depth of Lambert's continued fraction for ``tan``: the remainder after
#: 12 levels is below 1e-17 of the value for ``|x| <= 1``.
_TAN_DEPTH = 12

#: Largest angle (rad) a body may turn about one axis in one sub-step; a
#: time step that asks for more is unstable.
MAX_TURN = 1.0

#: Quaternion component pairs turned by ``+theta / 2`` when a body turns
#: by ``theta`` about its axis ``k`` (``q <- q (cos, sin e_k)``), and the
#: pair of ``L`` components turned by ``+theta`` (``L <- R_k(theta)^T L``).
QUATERNION_PAIRS = {0: ((0, 1), (3, 2)), 1: ((0, 2), (1, 3)),
                    2: ((0, 3), (2, 1))}
MOMENTUM_PAIRS = {0: (2, 1), 1: (0, 2), 2: (1, 0)}


def tan(x):
    """``tan x`` for ``|x| <= 1`` (float or array), by Lambert's continued
    fraction ``x / (1 - x**2 / (3 - x**2 / (5 - ...)))``: ``+ - * /``
    only, odd bitwise (``tan(-x) == -tan(x)``)."""
    x2 = x * x
    t = 0.0
    for k in range(_TAN_DEPTH, 0, -1):
        t = x2 / ((2 * k + 1) - t)
    return x / (1.0 - t)


def shear_coefficients(t):
    """``(a, b)`` of the three shears of a plane rotation by ``2 atan(t)``:
    ``a = -t``, ``b = 2 t / (1 + t**2)``; odd in ``t`` bitwise."""
    return -t, (t + t) / (1.0 + t * t)


def rotate_pair(counts, i, j, a, b):
    """Turn the components ``(i, j)`` of ``counts`` (``[b, m]`` float
    whole numbers, modified in place) by the three rounded shears of
    ``(a, b)`` (``[b]`` each): ``u += round_odd(a v)``, ``v +=
    round_odd(b u)``, ``u += round_odd(a v)`` for ``u, v = counts[:, i],
    counts[:, j]``."""
    u, v = counts[:, i], counts[:, j]
    u += round_odd(a * v)
    v += round_odd(b * u)
    u += round_odd(a * v)


def turn_about_axis(q_counts, l_counts, k, theta):
    """The free rotation about body axis ``k`` by ``theta`` (``[b]`` rad,
    a function of ``L_k`` only), on the counts of the orientation
    ``q_counts`` ``[b, 4]`` and angular momentum ``l_counts`` ``[b, 3]``
    (float whole numbers, modified in place)."""
    check_turn(theta)
    u = tan(0.25 * theta)  # tan of a quarter: the quaternion turns by half
    a, b = shear_coefficients(u)
    for i, j in QUATERNION_PAIRS[k]:
        rotate_pair(q_counts, i, j, a, b)
    # The same angle, doubled exactly in the algebra of tangents.
    a, b = shear_coefficients((u + u) / (1.0 - u * u))
    rotate_pair(l_counts, *MOMENTUM_PAIRS[k], a, b)


def turn_linear(q_counts, l_counts, ch, inertia, l_quantum):
    """The free rotation of linear bodies by ``ch`` (ASE time units):
    about the body axis along ``L`` (axis 0 is the line, ``L_0 = 0``) by
    ``theta = ch |L| / I``, with ``L`` unchanged.

    Written as a turn about axis 0 by ``beta``, about axis 1 by ``theta``
    and about axis 0 by ``-beta``, ``beta`` the angle of ``(L_1, L_2)``
    taken in ``(-pi/2, pi/2]`` (``theta`` changing sign with it): the
    outer two undo each other's rounding bitwise under ``-ch``, as the
    inner one does itself.  ``inertia`` ``[b]`` (amu Å**2); ``l_counts``
    ``[b, 3]`` is read only.
    """
    l1, l2 = l_counts[:, 1] * l_quantum, l_counts[:, 2] * l_quantum
    norm = np.sqrt(l1 * l1 + l2 * l2)
    sign = np.where(l1 < 0.0, -1.0, 1.0)
    # tan(beta / 2) = sin / (1 + cos) with cos >= 0: |t| <= 1, no pole.
    with np.errstate(invalid='ignore', divide='ignore'):
        t_beta = np.where(norm > 0.0, sign * l2 / (norm + sign * l1), 0.0)
    theta = sign * ch * norm / inertia
    check_turn(theta)
    # The quaternion turns by half the angle: tan(beta / 4) from
    # t = tan(beta / 2) by t / (1 + sqrt(1 + t**2)).
    t_quarter = t_beta / (1.0 + np.sqrt(1.0 + t_beta * t_beta))
    for t, k in ((t_quarter, 0), (tan(0.25 * theta), 1), (-t_quarter, 0)):
        a, b = shear_coefficients(t)
        for i, j in QUATERNION_PAIRS[k]:
            rotate_pair(q_counts, i, j, a, b)


def check_turn(theta):
    """Raise ValueError if a sub-step turns a body by more than
    :data:`MAX_TURN` (or by a non-finite angle)."""
    largest = float(np.max(np.abs(theta), initial=0.0))
    if not largest <= MAX_TURN:
        raise ValueError(largest)


def rotation_matrices(q):
    """``[b, 3, 3]``: the rotations of ``q / |q|`` for quaternions ``q``
    ``[b, 4]`` (any length), body frame to lab; products and sums in a
    fixed order (the same bits on every CPU)."""
    w, x, y, z = (q[:, i] for i in range(4))
    ww, xx, yy, zz = w * w, x * x, y * y, z * z
    s = 2.0 / ((ww + xx) + (yy + zz))
    xy, xz, yz = x * y, x * z, y * z
    wx, wy, wz = w * x, w * y, w * z
    a = np.empty((len(q), 3, 3), dtype=np.result_type(q, 1.0))
    a[:, 0, 0] = 1.0 - s * (yy + zz)
    a[:, 0, 1] = s * (xy - wz)
    a[:, 0, 2] = s * (xz + wy)
    a[:, 1, 0] = s * (xy + wz)
    a[:, 1, 1] = 1.0 - s * (xx + zz)
    a[:, 1, 2] = s * (yz - wx)
    a[:, 2, 0] = s * (xz - wy)
    a[:, 2, 1] = s * (yz + wx)
    a[:, 2, 2] = 1.0 - s * (xx + yy)
    return a


def rotation_derivatives(q):
    """``[b, 4, 3, 3]``: ``dA/dq_k`` of :func:`rotation_matrices` at
    quaternions ``q`` ``[b, 4]``, by complex steps (exact to rounding: the
    rotation is a rational function of ``q``).  For the adjoint."""
    step = 1e-30
    out = np.empty((len(q), 4, 3, 3))
    for k in range(4):
        shifted = q.astype(complex)
        shifted[:, k] += 1j * step
        out[:, k] = rotation_matrices(shifted).imag / step
    return out


def quaternion_product(a, b):
    """``[b, 4]``: ``a b`` of quaternions ``(w, x, y, z)`` (any dtype)."""
    aw, ax, ay, az = (a[:, i] for i in range(4))
    bw, bx, by, bz = (b[:, i] for i in range(4))
    return np.stack([aw * bw - ax * bx - ay * by - az * bz,
                     aw * bx + ax * bw + ay * bz - az * by,
                     aw * by - ax * bz + ay * bw + az * bx,
                     aw * bz + ax * by - ay * bx + az * bw], axis=1)


def rotation_quaternion(phi):
    """``[b, 4]``: the unit quaternion of the rotation vectors ``phi``
    ``[b, 3]`` (rad; any dtype, complex for complex steps)."""
    square = (phi * phi).sum(axis=1)
    small = np.abs(square) < 1e-12
    norm = np.sqrt(np.where(small, 1.0, square))
    # sin(|phi| / 2) / |phi|, its series below 1e-6 rad.
    sinc = np.where(small, 0.5 - square / 48.0, np.sin(0.5 * norm) / norm)
    cos = np.where(small, 1.0 - square / 8.0, np.cos(0.5 * norm))
    return np.concatenate([cos[:, None], sinc[:, None] * phi], axis=1)


def apply_rotations(a_bcc, v_bxc):
    """``[b, x, 3]``: ``A v`` for each body's rotation ``a_bcc`` ``[b, 3,
    3]`` and its vectors ``v_bxc`` ``[b, x, 3]``, summed ``(x + y) + z``."""
    return ((a_bcc[:, None, :, 0] * v_bxc[:, :, 0:1]
             + a_bcc[:, None, :, 1] * v_bxc[:, :, 1:2])
            + a_bcc[:, None, :, 2] * v_bxc[:, :, 2:3])


def apply_transposed(a_bcc, v_bc):
    """``[b, 3]``: ``A^T v`` for each body, summed ``(x + y) + z``."""
    return ((a_bcc[:, 0, :] * v_bc[:, 0:1] + a_bcc[:, 1, :] * v_bc[:, 1:2])
            + a_bcc[:, 2, :] * v_bc[:, 2:3])


def cross(u, v):
    """``u x v`` over the last axis (length 3) of two arrays of one shape,
    in a fixed order of products."""
    out = np.empty(np.broadcast_shapes(u.shape, v.shape))
    out[..., 0] = u[..., 1] * v[..., 2] - u[..., 2] * v[..., 1]
    out[..., 1] = u[..., 2] * v[..., 0] - u[..., 0] * v[..., 2]
    out[..., 2] = u[..., 0] * v[..., 1] - u[..., 1] * v[..., 0]
    return out


def atom_sum(v_bxc):
    """``[b, 3]``: the sum over each body's atoms (``[b, x, 3]``), in atom
    order."""
    total = v_bxc[:, 0].copy()
    for i in range(1, v_bxc.shape[1]):
        total += v_bxc[:, i]
    return total


def principal_frame(positions_xc, masses_x):
    """A body's centre of mass ``[3]``, principal moments ``[3]`` (amu
    Å**2, ascending) and body-frame coordinates ``[x, 3]`` of its atoms
    (``positions_xc`` ``[x, 3]`` Å, ``masses_x`` ``[x]`` amu), the frame
    right-handed.  A linear body's line is axis 0 (moment 0)."""
    m_x1 = masses_x[:, None]
    centre = (m_x1 * positions_xc).sum(axis=0) / masses_x.sum()
    r_xc = positions_xc - centre
    inertia = np.eye(3) * (m_x1 * r_xc**2).sum() - (m_x1 * r_xc).T @ r_xc
    moments, axes = np.linalg.eigh(inertia)
    if np.linalg.det(axes) < 0:
        axes[:, 2] = -axes[:, 2]
    body_xc = r_xc @ axes
    if moments[0] <= 1e-9 * moments[2]:
        # On a line: exactly on axis 0.
        moments[0] = 0.0
        body_xc[:, 1:] = 0.0
    return centre, moments, body_xc


def kabsch(body_xc, relative_xc, masses_x):
    """The rotation ``[3, 3]`` (body to lab) that best lays ``body_xc``
    onto ``relative_xc`` (``[x, 3]``, centred) by mass-weighted least
    squares."""
    h = (masses_x[:, None] * relative_xc).T @ body_xc
    u, _, vt = np.linalg.svd(h)
    d = np.sign(np.linalg.det(u @ vt)) or 1.0
    return u @ np.diag([1.0, 1.0, d]) @ vt


def quaternion_of(a):
    """The unit quaternion ``[4]`` ``(w, x, y, z)`` of a rotation ``a``
    ``[3, 3]`` (Shepperd's method: the largest of the four squares)."""
    trace = np.trace(a)
    squares = [1.0 + trace, 1.0 + 2 * a[0, 0] - trace,
               1.0 + 2 * a[1, 1] - trace, 1.0 + 2 * a[2, 2] - trace]
    k = int(np.argmax(squares))
    s = 2.0 * math.sqrt(squares[k])
    if k == 0:
        q = [s / 4, (a[2, 1] - a[1, 2]) / s, (a[0, 2] - a[2, 0]) / s,
             (a[1, 0] - a[0, 1]) / s]
    elif k == 1:
        q = [(a[2, 1] - a[1, 2]) / s, s / 4, (a[0, 1] + a[1, 0]) / s,
             (a[0, 2] + a[2, 0]) / s]
    elif k == 2:
        q = [(a[0, 2] - a[2, 0]) / s, (a[0, 1] + a[1, 0]) / s, s / 4,
             (a[1, 2] + a[2, 1]) / s]
    else:
        q = [(a[1, 0] - a[0, 1]) / s, (a[0, 2] + a[2, 0]) / s,
             (a[1, 2] + a[2, 1]) / s, s / 4]
    q = np.array(q)
    return q / np.linalg.norm(q)
