"""ReversibleNPT: constant pressure with the whole cell free (ASE's
``MTKNPT``), run back exactly.

The cell is kept lower triangular in ASE's rows (``a`` along x, ``b`` in
the xy plane: no rotation, six numbers).  It is ``cell0 M`` with ``M``
lower triangular (the identity at construction); the atoms sit at ``x =
rho M`` (rows) and carry ``p = pi M^-T``, so ``pi = p M^T`` is conjugate
to ``rho``.  The exact variables are ``rho``, ``pi``, the six entries of
``M`` ('barostat_position', in the order ``M00 M10 M11 M20 M21 M22``)
and their momenta ``P`` ('barostat_momentum').  With ``G = M M^T``::

    H = sum pi G^-1 pi^T / (2m) + U(rho M, cell0 M) + P_ext V0 det M
        + |P|**2 / (2W) + kT (ln M11 + 2 ln M22)

The last term is MTK's measure for a flexible cell: their ensemble weighs
a cell ``h`` (nine numbers) by ``V**(1-3) dh``; writing ``h = L Q`` (``L``
lower triangular, ``Q`` a rotation, on which nothing depends) gives ``dh =
L00**2 L11 dL dQ``, so the lower-triangular cell carries ``V**-2 L00**2
L11 = L11**-1 L22**-2``, which is ``exp(-H/kT)``'s factor above (``L =
cell0 M``, ``cell0`` lower triangular).  ``d rho d pi = dx dp`` as for the
isotropic barostat.

The splitting is that of docs/pressure.md ("The derivation"), each part a
shear:

* kinetic: ``rho += h q / m`` with ``q = p M^-1`` (``p = pi M^-T``), and
  ``P += h sum q^T p / m`` (the lower-triangular entries);
* potential: ``pi += h F M^T`` and ``P += h (-V M^-T (sigma + P_ext) -
  J)``, ``sigma`` ASE's stress (``dU/dM = V M^-T sigma`` at fixed
  ``rho``: a change ``dM`` strains the system by ``M^-1 dM``), ``J`` the
  derivative of the measure term (``kT / M11`` and ``2 kT / M22`` on the
  diagonal);
* piston: ``M += h P / W``.

``W = (N + 1) kT pdamp**2`` per entry, ASE's ``MTKNPT`` mass (the strain
rate ``M^-1 dM/dt`` is ASE's cell velocity at ``M = 1``).  The O step
gives ``pi`` the noise ``xi M^T`` of the mass ``m`` (the covariance of
``pi`` at fixed ``M`` is ``m kT G``), and the piston its own friction
``1 / pdamp`` and noise.  Every product of a row by a matrix and every
inverse is written in ``+ - * /``
(:func:`~ase_reversible.core.portable.rows_times_matrix`, the triangular
inverse below): the same bits on every CPU.

Gradients.  Each sub-step has its adjoint rule, as for the isotropic
barostat; the derivatives of ``F M^T`` and of the piston's force in the
six entries of ``M`` come from central differences (twelve calls for
forces and stress at a step's positions, shared by its kick and push),
and ``d g / d rho = sum_k d(F M^T)/d M_k`` (the mixed second derivatives
of ``U`` being equal).  Derivatives of cheap functions of ``M`` (the
drift, the kinetic push, what the atoms show) are central differences
too, with no force call.
"""

from __future__ import annotations

import math

import numpy as np

from ...adjoint.hessian import DEFAULT_FD_STEP
from ...core.codec import encode, round_odd
from ...core.portable import dot, rows_times_matrix
from ...errors import UnstableIntegrationError
from ..hamiltonian import Drift
from ..langevin import exact_o_step, exact_ratio, without_net_momentum
from .friction import ScaledFriction, past_the_anchor
from .isotropic import ReversibleIsotropicNPT
from .system import (DRIFT, KINETIC, LAMBDA, LAMBDA_MIN, P_LAMBDA, PISTON,
                     VIRIAL, KineticKick, NPTHamiltonian, Piston,
                     ScaledKick, VirialKick)

#: The entries of the lower-triangular ``M`` the variables hold, in order.
ROWS, COLUMNS = np.array([0, 1, 1, 2, 2, 2]), np.array([0, 0, 1, 0, 1, 2])


def lower_matrix(values):
    """The 3x3 lower-triangular matrix of six entries (``ROWS, COLUMNS``)."""
    m = np.zeros((3, 3))
    m[ROWS, COLUMNS] = values
    return m


def lower_inverse(m):
    """The inverse of a lower-triangular 3x3 matrix, in ``+ - * /``."""
    a, b, c = m[0, 0], m[1, 0], m[1, 1]
    d, e, f = m[2, 0], m[2, 1], m[2, 2]
    inverse = np.zeros((3, 3))
    inverse[0, 0], inverse[1, 1], inverse[2, 2] = 1.0 / a, 1.0 / c, 1.0 / f
    inverse[1, 0] = -b / (a * c)
    inverse[2, 1] = -e / (c * f)
    inverse[2, 0] = (b * e - c * d) / (a * c * f)
    return inverse


#: Step of the central differences in the entries of ``M`` (relative to
#: the largest ``|rho|``, so that atoms move by about 1e-5 Å, the step of
#: :data:`~ase_reversible.adjoint.hessian.DEFAULT_FD_STEP`).
def _entry_step(system):
    return DEFAULT_FD_STEP / max(1.0, float(np.abs(system.x.floats).max()))


def entry_gradient(function, m, d):
    """``d function / d M_k`` for the six entries, by central differences
    of step ``d``: ``function(M)`` returns a float or an array."""
    out = []
    for a, b in zip(ROWS, COLUMNS):
        plus, minus = m.copy(), m.copy()
        plus[a, b] += d
        minus[a, b] -= d
        out.append((np.asarray(function(plus)) - np.asarray(
            function(minus))) / (2 * d))
    return np.array(out)


def is_lower_triangular(cell):
    """Whether a cell (rows) has ``a`` along x and ``b`` in the xy plane."""
    cell = np.asarray(cell)
    return bool(cell[0, 1] == 0 and cell[0, 2] == 0 and cell[1, 2] == 0)


class CellHamiltonian(NPTHamiltonian):
    """The atoms in scaled variables under a lower-triangular ``M`` (six
    entries in ``lam``, their momenta in ``p_lam``); the atoms show ``x =
    rho M``, ``p = pi M^-T`` and the cell ``cell0 M``."""

    dynamics_name = 'ReversibleNPT'

    def __init__(self, atoms, grid, counts, masses_n, project, purity):
        super().__init__(atoms, grid, counts, masses_n, project, purity)
        self.drift = CellDrift(self)
        self.kick = CellKick(self)
        self._matrices = self._velocities = None

    @staticmethod
    def barostat_mass(n_atoms, kT, pdamp):
        """``W = (N + 1) kT pdamp**2``, eV (ASE time)**2 (ASE's MTKNPT)."""
        return (n_atoms + 1) * kT * (pdamp * pdamp)

    def matrices(self):
        """``(M, M^-1)`` of the present cell variable (cached)."""
        label = self.lam.label
        if self._matrices is None or self._matrices[0] != label:
            m = lower_matrix(self.lam.floats)
            self._matrices = (label, m, lower_inverse(m))
        return self._matrices[1], self._matrices[2]

    def lam_value(self) -> float:
        """The smallest diagonal entry of ``M`` (what the collapse check
        and the noise bound read)."""
        m = self.matrices()[0]
        return float(min(m[0, 0], m[1, 1], m[2, 2]))

    # -- what the atoms show ----------------------------------------------

    def show_positions(self):
        positions = self.atoms.arrays['positions']
        if self.lam is None:
            self.x.write_floats(positions)
        else:
            positions[:] = rows_times_matrix(self.x.floats,
                                             self.matrices()[0])

    def shown_positions(self):
        return rows_times_matrix(self.x.floats, self.matrices()[0])

    def shown_cell(self):
        return rows_times_matrix(self.cell0, self.matrices()[0])

    def show_cell(self):
        """Write ``cell0 M`` into the atoms' cell."""
        cell = self.atoms.cell.array
        cell[:] = self.shown_cell()
        self.shown_cell_bytes = cell.tobytes()

    def shown_momenta(self):
        key = (self.p.label, self.lam.label)
        if self._shown_key != key:
            self._shown_nc[:] = rows_times_matrix(
                self.p.floats, self.matrices()[1].T)
            self._shown_key = key
        return self._shown_nc

    def counts_of(self, positions_nc, momenta_nc):
        m, inverse = self.matrices()
        return (encode(rows_times_matrix(positions_nc, inverse),
                       self.x.quantum, 'position'),
                encode(rows_times_matrix(momenta_nc, m.T), self.p.quantum,
                       'momentum'))

    @staticmethod
    def start_counts(quantum):
        one = round(1.0 / quantum)
        return {LAMBDA: np.array([one, 0, one, 0, 0, one], np.int64),
                P_LAMBDA: np.zeros(6, np.int64)}

    @staticmethod
    def valid_counts(counts):
        return bool(counts[0] > 0 and counts[2] > 0 and counts[5] > 0)

    @staticmethod
    def cell_at(cell0, values):
        return rows_times_matrix(cell0, lower_matrix(values))

    @staticmethod
    def record_counts(variable):
        return variable.ints.tolist()

    # -- energies ---------------------------------------------------------

    def velocities(self):
        """``(p, q / m)``: the shown momenta and ``p M^-1 / m`` (cached
        for the drift and the kinetic push, which read the same)."""
        key = (self.p.label, self.lam.label)
        if self._velocities is None or self._velocities[0] != key:
            p_nc = self.shown_momenta()
            self._velocities = (key, p_nc, rows_times_matrix(
                p_nc, self.matrices()[1]) / self.m_n1)
        return self._velocities[1], self._velocities[2]

    def kinetic_energy(self):
        p_nc = self.shown_momenta()
        return 0.5 * dot(p_nc / self.m_n1, p_nc)

    def volume(self) -> float:
        m = self.matrices()[0]
        return self.V0 * (m[0, 0] * m[1, 1] * m[2, 2])

    def barostat_energy(self) -> float:
        """``P V + |P|**2 / 2W + kT (ln M11 + 2 ln M22)``, eV."""
        m = self.matrices()[0]
        p = self.p_lam.floats
        return (self.pressure * self.volume() + 0.5 * dot(p, p) / self.W
                + self.kT * (math.log(m[1, 1]) + 2.0 * math.log(m[2, 2])))


class CellDrift(Drift):
    """``rho += round_odd(c h pi G^-1 / m / q_x)``, ``pi G^-1 = q``.

    The positions are shown by the piston that follows each drift in the
    step (and by :meth:`rollback`): nothing reads them in between, and a
    product with ``M`` for all atoms is a quarter of the step's own cost
    at 500 atoms (profiled)."""

    def apply(self, prepared):
        ch = prepared[0]
        s = self.system
        y_nc = s.velocities()[1] * (ch / s.x.quantum)
        round_odd(y_nc, out=y_nc)
        s.x.add_integers(y_nc)
        self._moved = None

    def adjoint(self, cotangents, ch):
        """``a_pi += c h (a_rho / m) M^-T M^-1``; ``a_M += c h d/dM
        [(a_rho / m) . pi M^-T M^-1]`` (central differences, no force
        call)."""
        cotangents.flush()
        s = self.system
        w_nc = cotangents['position'] / s.m_n1
        pi_nc = s.p.floats
        m, inverse = s.matrices()

        def along(m_):
            inv = lower_inverse(m_)
            return dot(w_nc, rows_times_matrix(
                rows_times_matrix(pi_nc, inv.T), inv))
        cotangents[LAMBDA] += ch * entry_gradient(along, m, 1e-6)
        cotangents['momentum'] += ch * rows_times_matrix(
            rows_times_matrix(w_nc, inverse.T), inverse)


class CellKick(ScaledKick):
    """``pi += round_odd(c h F M^T / q_p)``, guarded as the kick is."""

    def apply(self, scale):
        s = self.system
        key = (self._key(), scale)
        if self._applied != key:
            self._applied = self._r_key = self._r_max = None
            m = s.matrices()[0]
            # The guard bounds the forces' noise times |scale|; the product
            # with M^T grows it by at most M's largest row sum.
            growth = float(np.abs(m).sum(axis=1).max())
            transpose = m.T / growth

            def transform(y_nc):
                y_nc[:] = rows_times_matrix(y_nc, transpose)
            f_used_nc = s.purity.rounded_kick(
                s.atoms, self.forces(), scale * growth, transform,
                out=self._r_nc, scratch=self._y_nc)
            if s.centre is not None:
                s.centre.balance(self._r_nc)
            self._f_cache = (key[0], f_used_nc)
            self._r_key = (key[0], scale * growth)
            self._applied = key
        self._r_max = s.p.add_integers(self._r_nc, self._r_max)

    def entry_derivatives(self):
        """``(D, dg)``: for each of the six entries of ``M``, the
        derivative at fixed ``rho`` of ``F M^T`` (``[6, n_atoms, 3]``,
        eV/Å) and of the piston's force (``[6, 6]``, eV), by central
        differences (twelve calls for forces and stress, positions and
        cell put back bit for bit).  ``sum_k a_k D_k`` is also the
        derivative of ``a . g`` in ``rho`` (the mixed second derivatives
        of ``U`` being equal)."""
        key = self._key()
        if self._second is not None and self._second[0] == key:
            return self._second[1]
        s = self.system
        atoms, rho_nc = s.atoms, s.x.floats.copy()
        virial = CellVirial(s)

        def at(m_):
            atoms.cell.array[:] = rows_times_matrix(s.cell0, m_)
            atoms.positions = rows_times_matrix(rho_nc, m_)
            f_nc = atoms.get_forces(apply_constraint=False)
            sigma = atoms.get_stress(voigt=True, apply_constraint=False)
            return np.concatenate([rows_times_matrix(f_nc, m_.T).ravel(),
                                   virial.force(sigma, m_)])
        try:
            both = entry_gradient(at, s.matrices()[0], _entry_step(s))
        finally:
            s.show_cell()
            s.show_positions()
        n = rho_nc.size
        derivatives = (both[:, :n].reshape((6,) + rho_nc.shape),
                       both[:, n:])
        self._second = (key, derivatives)
        return derivatives

    def adjoint(self, cotangents, ch):
        """``a_rho += c h ((dF/dx)^T (a_pi M)) M^T`` (one product) and
        ``a_M += c h a_pi . d(F M^T)/dM``."""
        cotangents.flush()
        s = self.system
        a_nc = np.array(cotangents['momentum'])
        if s.centre is not None:
            s.centre.pull_back(a_nc)
        if not a_nc.any():
            return
        m = s.matrices()[0]
        dx_nc, _ = cotangents.product(s.atoms, rows_times_matrix(a_nc, m))
        cotangents.products += 1
        cotangents['position'] += ch * rows_times_matrix(dx_nc, m.T)
        d_knc = self.entry_derivatives()[0]
        cotangents[LAMBDA] += ch * np.array([dot(a_nc, d) for d in d_knc])


class CellVirial(VirialKick):
    """``P += round_odd(c h (-V M^-T (sigma + P_ext) - J) / q)`` on the
    six entries; guarded as :class:`~.system.VirialKick` is."""

    def push(self, clean):
        """float ``[6]``: the piston's force (eV) from the stress, the one
        from a clean neighbour list if ``clean``."""
        kick = self.system.kick
        return self.force(kick.clean_stress() if clean else kick.stress())

    def force(self, sigma, m=None):
        """The six entries of the piston's force (eV) for the stress
        ``sigma`` (Voigt, eV/Å**3), at ``M = m`` (default: the present)."""
        s = self.system
        m, inverse = s.matrices() if m is None else (m, lower_inverse(m))
        volume = s.V0 * (m[0, 0] * m[1, 1] * m[2, 2])
        xx, yy, zz, yz, xz, xy = (float(v) for v in sigma)
        p = s.pressure
        full = np.array([[xx + p, xy, xz], [xy, yy + p, yz],
                         [xz, yz, zz + p]])
        g = rows_times_matrix(inverse.T, full) * (-volume)
        g[1, 1] -= s.kT / m[1, 1]
        g[2, 2] -= 2.0 * s.kT / m[2, 2]
        return g[ROWS, COLUMNS]

    def adjoint(self, cotangents, ch):
        """``a_rho += c h sum_k a_k D_k``, ``a_M += c h a . dg/dM``
        (:meth:`CellKick.entry_derivatives`)."""
        cotangents.flush()
        a_k = np.array(cotangents[P_LAMBDA])
        if not a_k.any():
            return
        d_knc, dg_kl = self.system.kick.entry_derivatives()
        cotangents['position'] += ch * np.tensordot(a_k, d_knc, axes=1)
        # dg_kl[k, l] = d g_l / d M_k.
        cotangents[LAMBDA] += ch * (dg_kl @ a_k)


class CellKinetic(KineticKick):
    """``P += round_odd(c h sum q^T p / m / q)`` (lower-triangular
    entries)."""

    def force(self):
        """float ``[6]``: the push ``sum q^T p / m`` (eV)."""
        p_nc, v_nc = self.system.velocities()
        return np.array([dot(v_nc[:, a], p_nc[:, b])
                         for a, b in zip(ROWS, COLUMNS)])

    def adjoint(self, cotangents, ch):
        """With ``A`` the lower-triangular matrix of ``a = a_P``: ``a_pi
        += c h pi (C + C^T) / m``, ``C = B B^T A B^T``, ``B = M^-T``;
        ``a_M`` by central differences of ``a . f`` (no force call)."""
        cotangents.flush()
        a_k = np.array(cotangents[P_LAMBDA])
        if not a_k.any():
            return
        s = self.system
        pi_nc, m_n1 = s.p.floats, s.m_n1
        a = lower_matrix(a_k)
        m, inverse = s.matrices()
        b = inverse.T
        c = b @ b.T @ a @ b.T

        def along(m_):
            inv = lower_inverse(m_)
            p_nc = rows_times_matrix(pi_nc, inv.T)
            q_nc = rows_times_matrix(p_nc, inv) / m_n1
            return dot(rows_times_matrix(q_nc, a), p_nc)
        cotangents[LAMBDA] += ch * entry_gradient(along, m, 1e-6)
        cotangents['momentum'] += ch * rows_times_matrix(pi_nc, c + c.T) \
            / m_n1


class CellPiston(Piston):
    """``M += round_odd(c h P / W / q)``; the diagonal must stay above
    :data:`~.system.LAMBDA_MIN`."""

    def momentum(self):
        """``P``, the six entries, eV ASE time."""
        return self.system.p_lam.floats

    def refuse_collapse(self):
        """Raise UnstableIntegrationError if the cell's deformation is too
        small along its diagonal."""
        m = self.system.matrices()[0]
        diagonal = (m[0, 0], m[1, 1], m[2, 2])
        if not min(diagonal) > LAMBDA_MIN:
            raise UnstableIntegrationError(
                'The cell collapsed: the diagonal of its deformation '
                f'reached {min(diagonal):.4g} (at most {LAMBDA_MIN} is '
                'allowed). The barostat is unstable or the pressure far '
                'too high for this system: use a larger pdamp, a smaller '
                'time step, or a pressure nearer the system\'s own. The '
                'step was not taken; the state is valid and reversible.')


class CellFriction(ScaledFriction):
    """The O step on ``pi``: ``pi' = c pi + (sigma xi) M^T``, exact through
    the information buffer; the piston's entries as in
    :class:`~.friction.ScaledFriction`."""

    def apply(self, prepared):
        atoms_part, piston_part = prepared
        forward, buffer, mask_k, sigma_k, key, zero_sum = atoms_part[:6]
        held = atoms_part.held
        s = self.system
        p = s.p
        x_k = p.ints.reshape(-1)
        xi_k = self.noise.normals(key, self.step_of())
        y_nc = rows_times_matrix((sigma_k * xi_k).reshape(self.shape),
                                 s.matrices()[0].T)
        noise_k = np.rint(y_nc).astype(np.int64).reshape(-1)
        if zero_sum is not None:
            noise_k = without_net_momentum(noise_k, *zero_sum)
        before = s.kinetic_energy()
        new_k = exact_o_step(buffer, x_k, noise_k, forward, mask_k,
                             past_the_anchor(s))
        self.hold_total(new_k, held)
        p.add_integers((new_k - x_k).astype(np.float64).reshape(self.shape))
        self.heat += s.kinetic_energy() - before
        if piston_part is not None:
            self.piston.apply(piston_part, self.noise.extra)

    def adjoint(self, cotangents, ch):
        """``pi' = c pi + P(s M^T)`` (``s`` the noise for the mass ``m``,
        ``P`` the removal of its net momentum): ``a_M[c, d] += sum_i
        (P^T a_pi')_ic s_id``, then ``a_pi = c a_pi'``; the piston's
        ``a_P *= c_piston``."""
        cotangents.flush()
        s = self.system
        atoms_part, piston_part = self.prepare(ch)
        s_nc = (s.p.quantum * atoms_part.sigma_k * self.noise.normals(
            atoms_part.key, self.step_of())).reshape(self.shape)
        a_nc = cotangents['momentum']
        if atoms_part.zero_sum is not None:
            a_nc = a_nc - (atoms_part.zero_sum[0] * a_nc).sum(axis=0)
        outer = a_nc.T @ s_nc
        cotangents[LAMBDA] += outer[ROWS, COLUMNS]
        cotangents['momentum'] *= exact_ratio(self.settings().friction,
                                              ch)[1]
        if piston_part is not None:
            cotangents[P_LAMBDA] *= exact_ratio(self.piston.friction, ch)[1]


class ReversibleNPT(ReversibleIsotropicNPT):
    """Constant pressure and temperature with the whole cell free, run
    back exactly: the counterpart of ASE's
    :class:`ase.md.nose_hoover_chain.MTKNPT`.

    As :class:`~ase_reversible.ReversibleIsotropicNPT` (the same
    arguments, restarts, refusals and Langevin thermostat, or Nosé's with
    ``thermostat='nose'``: :mod:`.cell_nose`), but the cell
    changes shape too: the six entries of a lower-triangular deformation
    ``M`` and their momenta are exact variables (:mod:`.cell`).  The
    atoms' cell must be lower triangular in ASE's rows (``a`` along x,
    ``b`` in the xy plane), as ``atoms.cell.standard_form()`` gives it.
    :attr:`barostat_position` is ``M`` (3x3), :attr:`barostat_momentum`
    its momenta (six, in the order ``M00 M10 M11 M20 M21 M22``).
    ``backpropagate`` gives gradients through the run; each step of the
    retrace costs twelve calls for forces and stress (the derivatives in
    ``M`` by central differences) besides the kick's product, and the
    barostat's gradients (``.thermostat['lambda']``, six, at fixed
    positions and momenta; ``['p_lambda']``) come in the order of the
    entries.
    """

    _ase_counterpart = 'MTKNPT'
    _system_class = CellHamiltonian
    _friction_class = CellFriction

    @staticmethod
    def _nose_class():
        """The class ``thermostat='nose'`` constructs."""
        from .cell_nose import ReversibleNoseNPT
        return ReversibleNoseNPT

    @staticmethod
    def _refuse_shape(atoms):
        from ase import Atoms
        if isinstance(atoms, Atoms) and not is_lower_triangular(
                atoms.cell.array):
            raise ValueError(
                'ReversibleNPT moves a lower-triangular cell (a along x, b '
                'in the xy plane: no rotation), and this one is not: '
                f'{atoms.cell.array.tolist()}. Rotate it first: '
                'cell, _ = atoms.cell.standard_form(); '
                'atoms.set_cell(cell, scale_atoms=True).')

    @staticmethod
    def _barostat_substeps(system):
        return {VIRIAL: CellVirial(system), PISTON: CellPiston(system),
                DRIFT: system.drift, KINETIC: CellKinetic(system)}

    def _loss_cotangents(self, ax_nc, ap_nc):
        # x = rho M, p = pi M^-T.
        s = self.system
        n = s.x.ints.shape
        ax_nc = np.zeros(n) if ax_nc is None else np.asarray(ax_nc, float)
        ap_nc = np.zeros(n) if ap_nc is None else np.asarray(ap_nc, float)
        rho_nc, pi_nc = s.x.floats, s.p.floats
        m, inverse = s.matrices()

        def shown(m_):
            return (dot(ax_nc, rows_times_matrix(rho_nc, m_))
                    + dot(ap_nc, rows_times_matrix(pi_nc,
                                                   lower_inverse(m_).T)))
        return {'position': rows_times_matrix(ax_nc, m.T),
                'momentum': rows_times_matrix(ap_nc, inverse),
                LAMBDA: entry_gradient(shown, m, 1e-6)}

    def _gradients_of(self, cotangents):
        # Back to (x, p) at fixed M: rho = x M^-1, pi = p M^T.
        s = self.system
        m, inverse = s.matrices()
        a_rho, a_pi = cotangents['position'], cotangents['momentum']
        x_nc, p_nc = s.shown_positions(), s.shown_momenta().copy()

        def held(m_):
            return (dot(a_rho, rows_times_matrix(x_nc, lower_inverse(m_)))
                    + dot(a_pi, rows_times_matrix(p_nc, m_.T)))
        a_m = np.array(cotangents[LAMBDA]) + entry_gradient(held, m, 1e-6)
        self._retrace_end = self._retrace_key()
        return (rows_times_matrix(a_rho, inverse.T),
                rows_times_matrix(a_pi, m),
                {'lambda': a_m, 'p_lambda': np.array(cotangents[P_LAMBDA])})

    @property
    def barostat_position(self):
        """``M`` (3x3, lower triangular): the cell is ``cell0 M``."""
        return self.system.matrices()[0].copy()

    @property
    def barostat_momentum(self):
        """The six momenta of ``M``'s entries, eV ASE time."""
        return self.system.p_lam.floats.copy()
