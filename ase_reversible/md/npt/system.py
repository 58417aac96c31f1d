"""The scaled system of :class:`~.isotropic.ReversibleIsotropicNPT`: its
exact variables, what the atoms show, and the sub-steps of the
Hamiltonian part (the derivation is in docs/pressure.md, "The
derivation")."""

from __future__ import annotations

import math

import numpy as np
from ase import units

from ...adjoint.hessian import DEFAULT_FD_STEP
from ...core.codec import (encode, guard_band_crossed, power_of_two_below,
                           round_odd)
from ...core.plans import SubStep
from ...core.portable import dot
from ...core.variables import ExactVariable
from ...errors import UnstableIntegrationError
from ...purity.settings import TARGET_CLEAN_RATE
from ..constraints import FixedCentre
from ..hamiltonian import Drift, Hamiltonian, Kick

LAMBDA, P_LAMBDA = 'barostat_position', 'barostat_momentum'
KICK, VIRIAL, PISTON, DRIFT, KINETIC, FRICTION = (
    'kick', 'virial', 'piston', 'drift', 'kinetic', 'friction')

#: Quantum of ``lambda`` (starts at 1): 2**-44 moves a position of 2**43
#: position quanta (the default grid's range over 1024) by half a quantum,
#: and leaves 2**9 of range.
LAMBDA_QUANTUM = 2.0**-44
#: Bits of ``sqrt(W kT)`` (the spread of ``p_lambda``) below its quantum:
#: 36 leave ``p_lambda`` a range of 2**17 spreads, for the far from
#: equilibrium start of a run at a pressure far from the system's own.
#: The piston's friction moves ``p_lambda`` by up to ``2**16`` quanta from
#: ``c p_lambda`` (the information buffer's digits mixed in), a jitter of
#: ``2**-20`` spreads a step, beside noise of 0.3 spreads at ``|dt| /
#: pdamp = 1/20``.
P_LAMBDA_BITS = 36
#: ``lambda`` below this stops the run: the volume would have fallen to
#: under 1/64 of the construction volume, a collapse, not a fluctuation.
LAMBDA_MIN = 0.25
#: Counts of ``rho`` and ``pi`` below this are recovered exactly from a
#: frame's ``x = lambda rho`` and ``p = pi / lambda`` (two roundings of
#: 2**-53 each); above, the record stores them.
RECOVERABLE = 2.0**50



def cell_volume(cell):
    """``|a . (b x c)|`` of a 3x3 cell (Å**3), in + - * only: the same bits
    on every CPU, which ``np.linalg.det`` does not promise."""
    (a0, a1, a2), (b0, b1, b2), (c0, c1, c2) = np.asarray(cell,
                                                          float).tolist()
    return abs(a0 * (b1 * c2 - b2 * c1) + a1 * (b2 * c0 - b0 * c2)
               + a2 * (b0 * c1 - b1 * c0))


def barostat_mass(n_atoms, kT, pdamp):
    """``W = (3N + 3) kT pdamp**2``, eV (ASE time)**2: ASE's MTK mass of
    ``ln lambda``, which is the mass of ``lambda`` at ``lambda = 1``."""
    return (3 * n_atoms + 3) * kT * (pdamp * pdamp)


class NPTHamiltonian(Hamiltonian):
    """The atoms in scaled variables: ``'position'`` holds ``rho``,
    ``'momentum'`` holds ``pi``; the atoms show ``x = lambda rho``, ``p =
    pi / lambda`` and the cell ``lambda cell0``.  ``lambda`` and
    ``p_lambda`` are exact variables of shape ``[1]``, set with
    :meth:`set_barostat`.  Other parameters as for
    :class:`~.hamiltonian.Hamiltonian`.
    """

    #: The integrator's name, for messages.
    dynamics_name = 'ReversibleIsotropicNPT'

    def __init__(self, atoms, grid, counts, masses_n, project, purity):
        self.lam = None
        super().__init__(atoms, grid, counts, masses_n, project, purity)
        self.drift = ScaledDrift(self)
        self.kick = ScaledKick(self)
        self._shown_nc = np.empty(self.p.ints.shape)
        self._shown_key = None

    def set_barostat(self, cell0, counts, quanta, temperature_K,
                     pressure_au, tdamp, pdamp):
        """Take ``lambda`` and ``p_lambda`` from ``counts`` (int64 ``[1]``
        by name) in ``quanta``, with the reference cell ``cell0`` (Å) and
        the settings (K, eV/Å**3, ASE time units)."""
        self.cell0 = np.array(cell0, dtype=float)
        self.V0 = cell_volume(self.cell0)
        self.lam = ExactVariable(LAMBDA, counts[LAMBDA], quanta[LAMBDA])
        self.p_lam = ExactVariable(P_LAMBDA, counts[P_LAMBDA],
                                   quanta[P_LAMBDA])
        self.variables.update({LAMBDA: self.lam, P_LAMBDA: self.p_lam})
        self.temperature_K = temperature_K
        self.kT = units.kB * temperature_K
        self.pressure = pressure_au
        self.tdamp, self.pdamp = tdamp, pdamp
        self.W = self.barostat_mass(len(self.m_n1), self.kT, pdamp)

    barostat_mass = staticmethod(barostat_mass)

    def set_dynamics(self, masses_n, project, purity):
        # A held total momentum outlives new masses or a new calculator.
        held = getattr(self, 'centre', None) is not None
        super().set_dynamics(masses_n, project, purity)
        if held:
            self.centre = FixedCentre(masses_n, np.ones(self.p.ints.shape))

    def hold_zero_momentum(self):
        """Hold the atoms' total momentum (the sum of the counts of ``pi``
        in each component) at exactly zero from now on: FixCom's integer
        balance (:class:`~ase_reversible.md.constraints.FixedCentre`) on
        every kick and O step, the present net momentum removed in
        proportion to mass.  ``p = pi / lambda`` (``pi M^-1`` for the
        whole cell) is linear in ``pi``, so the atoms' momenta then sum to
        zero up to the float rounding of each."""
        self.centre = FixedCentre(self.m_n1[:, 0], np.ones(self.p.ints.shape))
        self.p.reset(self.centre.balanced_counts(self.p.ints))

    def lam_value(self) -> float:
        """``lambda``, its exact float image."""
        return float(self.lam.floats[0])

    # -- what the atoms show ----------------------------------------------

    def show_positions(self):
        positions = self.atoms.arrays['positions']
        self.x.write_floats(positions)
        if self.lam is not None:
            positions *= self.lam_value()

    def shown_positions(self):
        """``lambda rho``, ``[n_atoms, 3]`` (a new array)."""
        return self.x.floats * self.lam_value()

    def shown_cell(self):
        """``lambda cell0``, 3x3 (a new array)."""
        return self.cell0 * self.lam_value()

    def show_cell(self):
        """Write ``lambda cell0`` into the atoms' cell."""
        cell = self.atoms.cell.array
        np.multiply(self.cell0, self.lam_value(), out=cell)
        #: The bytes of the cell shown: a cell that still has them is
        #: the one this dynamics set, not the user's.
        self.shown_cell_bytes = cell.tobytes()

    def shown_momenta(self):
        return self.divided_momenta(self.lam)

    def show(self):
        self.show_cell()
        super().show()

    def counts_of(self, positions_nc, momenta_nc):
        """``(rho, pi)`` counts (int64) of shown positions and momenta at
        the present ``lambda``."""
        lam = self.lam_value()
        return (encode(positions_nc / lam, self.x.quantum, 'position'),
                encode(momenta_nc * lam, self.p.quantum, 'momentum'))

    # -- the barostat's counts, for the restart record --------------------

    @staticmethod
    def start_counts(quantum):
        """Counts of the undeformed cell and a piston at rest, by name,
        for the cell's quantum ``quantum``."""
        return {LAMBDA: np.array([round(1.0 / quantum)], np.int64),
                P_LAMBDA: np.zeros(1, np.int64)}

    @staticmethod
    def valid_counts(counts):
        """Whether the cell's counts (int64) describe a cell."""
        return bool(counts[0] > 0)

    @staticmethod
    def cell_at(cell0, values):
        """The cell (3x3, Å) the cell's variable ``values`` (float)
        make of ``cell0``."""
        return cell0 * values[0]

    @staticmethod
    def record_counts(variable):
        """A barostat variable's counts as the record keeps them."""
        return int(variable.ints[0])

    # -- energies ---------------------------------------------------------

    def kinetic_energy(self):
        """``sum pi**2 / (2 m lambda**2)``, eV."""
        lam = self.lam_value()
        return 0.5 * self.momentum_square() / (lam * lam)

    def volume(self) -> float:
        """``lambda**3 V0``, Å**3."""
        lam = self.lam_value()
        return lam * lam * lam * self.V0

    def barostat_energy(self) -> float:
        """``P V + p_lambda**2 / 2W - 2 kT ln lambda``, eV."""
        # libm's log may differ between CPUs in the last bit: only the
        # energy check reads this, never a step.
        p_lam = float(self.p_lam.floats[0])
        return (self.pressure * self.volume() + 0.5 * p_lam * p_lam / self.W
                - 2.0 * self.kT * math.log(self.lam_value()))


class ScaledDrift(Drift):
    """``rho += round_odd(c h pi / (m lambda**2) / q_x)``."""

    def apply(self, prepared):
        s = self.system
        lam = s.lam_value()
        self._drift(prepared, (s.p.label, s.lam.label, prepared[0]),
                    1.0 / (lam * lam))

    def adjoint(self, cotangents, ch):
        """``a_pi += c h a_rho / (m lambda**2)``; ``a_lambda -= 2 c h
        a_rho . pi / (m lambda**3)``."""
        cotangents.flush()
        s = self.system
        lam = s.lam_value()
        w_nc = np.divide(cotangents['position'], s.m_n1)
        cotangents[LAMBDA] -= 2.0 * ch / (lam * lam * lam) * dot(
            w_nc, s.p.floats)
        cotangents['momentum'] += (ch / (lam * lam)) * w_nc


class ScaledKick(Kick):
    """``pi += round_odd(c h lambda F(lambda rho) / q_p)``; the forces and
    the stress come from one calculator call per value of ``rho`` and
    ``lambda``."""

    def forget(self):
        super().forget()
        self._stress = self._saved_stress = self._applied = None
        self._second = None  # (key, lambda_derivatives())

    def _key(self):
        s = self.system
        return (s.x.label, s.lam.label)

    def forces(self):
        """Forces ``[n_atoms, 3]`` (eV/Å) at the shown positions and cell."""
        key = self._key()
        if self._f_cache is not None and self._f_cache[0] == key:
            return self._f_cache[1]
        s = self.system
        f_nc = s.purity.forces(s.atoms)
        self._f_cache = (key, f_nc)
        return f_nc

    def stress(self):
        """The stress (Voigt, eV/Å**3, ASE's sign) at the shown positions
        and cell, from the call that gave the forces."""
        key = self._key()
        if self._stress is not None and self._stress[0] == key:
            return self._stress[1]
        self.forces()
        sigma = np.array(self.system.atoms.get_stress(
            voigt=True, apply_constraint=False), dtype=float)
        self._stress = (key, sigma)
        return sigma

    def held_stress(self):
        """The stress the steps left for the present positions and cell,
        or None (computing nothing)."""
        stress = self._stress
        return stress[1] if stress is not None and \
            stress[0] == self._key() else None

    def stress_trace(self):
        """``tr(sigma)`` (eV/Å**3) of :meth:`stress`."""
        sigma = self.stress()
        return float(sigma[0]) + float(sigma[1]) + float(sigma[2])

    def clean_stress(self):
        """The stress from a neighbour list built at exactly these
        positions (guarded rounding's clean recomputation)."""
        s = self.system
        f_nc = s.purity.clean_forces(s.atoms)
        self._f_cache = (self._key(), f_nc)
        sigma = np.array(s.atoms.get_stress(voigt=True,
                                            apply_constraint=False),
                         dtype=float)
        self._stress = (self._key(), sigma)
        return sigma

    def clean_stress_trace(self):
        """``tr(sigma)`` of :meth:`clean_stress`."""
        sigma = self.clean_stress()
        return float(sigma[0]) + float(sigma[1]) + float(sigma[2])

    def held(self, label=None):
        key = self._key()
        if label is not None and label != key[0]:
            return None, None
        f, r = self._f_cache, self._r_key
        return (f[1] if f is not None and f[0] == key else None,
                (r[1], self._r_nc) if r is not None and r[0] == key
                else None)

    def apply(self, scale):
        # Kick.apply's cache key is (label, scale); here the rounding's
        # scale is lambda times the step's, which held() reports.
        s = self.system
        key = (self._key(), scale)
        if self._applied != key:
            self._applied = self._r_key = self._r_max = None
            effective = scale * s.lam_value()
            f_used_nc = s.purity.rounded_kick(
                s.atoms, self.forces(), effective, s.project, out=self._r_nc,
                scratch=self._y_nc)
            if s.centre is not None:
                s.centre.balance(self._r_nc)
            self._f_cache = (key[0], f_used_nc)
            self._r_key = (key[0], effective)
            self._applied = key
        self._r_max = s.p.add_integers(self._r_nc, self._r_max)

    def lambda_derivatives(self):
        """``(D, dS)``: the derivatives in ``lambda`` at fixed ``rho`` of
        ``lambda F`` (``[n_atoms, 3]``, eV/Å) and of ``S = -lambda**2 V0
        tr(sigma)`` (eV), by central differences (two calls for forces
        and stress, positions and cell put back bit for bit).  ``D`` is
        also ``dG / d rho`` (``G`` the piston's force), the two mixed
        second derivatives of ``U`` being equal."""
        key = self._key()
        if self._second is not None and self._second[0] == key:
            return self._second[1]
        s = self.system
        atoms, lam, rho_nc = s.atoms, s.lam_value(), s.x.floats.copy()
        d = DEFAULT_FD_STEP / max(1.0, float(np.abs(rho_nc).max()))
        values = []
        try:
            for at in (lam + d, lam - d):
                np.multiply(s.cell0, at, out=atoms.cell.array)
                atoms.positions = rho_nc * at
                f_nc = atoms.get_forces(apply_constraint=False)
                sigma = atoms.get_stress(voigt=True, apply_constraint=False)
                trace = float(sigma[0]) + float(sigma[1]) + float(sigma[2])
                values.append((at * f_nc, -(at * at) * s.V0 * trace))
        finally:
            s.show_cell()
            s.show_positions()
        (f_plus, s_plus), (f_minus, s_minus) = values
        derivatives = ((f_plus - f_minus) / (2 * d),
                       (s_plus - s_minus) / (2 * d))
        self._second = (key, derivatives)
        return derivatives

    def adjoint(self, cotangents, ch):
        """``a_rho += c h lambda**2 (dF/dx)^T a_pi`` (one product) and
        ``a_lambda += c h a_pi . d(lambda F)/d lambda``."""
        cotangents.flush()
        s = self.system
        w_nc = np.array(cotangents['momentum'])
        if s.centre is not None:
            s.centre.pull_back(w_nc)
        if not w_nc.any():
            return
        lam = s.lam_value()
        dx_nc, _ = cotangents.product(s.atoms, w_nc)
        cotangents.products += 1
        cotangents['position'] += (ch * lam * lam) * dx_nc
        cotangents[LAMBDA] += ch * dot(w_nc, self.lambda_derivatives()[0])

    def stress_is_clean(self):
        """Whether the stress held was taken right after a clean
        recomputation of the forces at these positions."""
        f, stress = self._f_cache, self._stress
        return (f is not None and stress is not None and f[0] == stress[0]
                and f[1] is getattr(self.system.purity, '_clean_nc', None))

    def checkpoint(self):
        super().checkpoint()
        self._saved_stress = self._stress

    def rollback(self):
        super().rollback()
        self._stress = self._saved_stress
        self._applied = None



class PistonPush(SubStep):
    """A push on the piston's momentum, ``p_lambda += round_odd(c h f /
    q)`` (``q`` its quantum), prepared as ``c h / q``; what it computes is
    kept under ``_key``, the labels of the state it read."""

    def __init__(self, system):
        self.system = system
        self._key = None

    def prepare(self, ch):
        return ch / self.system.p_lam.quantum


class VirialKick(PistonPush):
    """``p_lambda += round_odd(c h G / q)``, ``G = -lambda**2 V0 (tr(sigma)
    + 3P) + 2 kT / lambda`` (see docs/pressure.md, "The derivation").

    Under guarded rounding the increment is a rounding like the kick's: if
    it lies within the stress's noise bound of a tie, the stress is
    recomputed from a clean neighbour list.  The rounded increment is kept
    for the next half step at the same positions and cell.
    """

    def push(self, clean):
        """float ``[entries of p_lambda]``: ``G`` (eV) from the stress, the
        one from a clean neighbour list if ``clean``."""
        kick = self.system.kick
        return np.array([self.force(kick.clean_stress_trace() if clean
                                    else kick.stress_trace())])

    def force(self, trace):
        """``G`` (eV) for the stress trace ``trace`` (eV/Å**3)."""
        s = self.system
        lam = s.lam_value()
        return (-(lam * lam) * s.V0 * (trace + 3.0 * s.pressure)
                + 2.0 * s.kT / lam)

    def apply(self, scale):
        s = self.system
        key = (s.x.label, s.lam.label, scale)
        if self._key != key:
            self._key = None
            kick = s.kick
            y_k = scale * self.push(clean=False)
            r_k = round_odd(y_k)
            if s.purity.mode == 'guarded' and not kick.stress_is_clean():
                bound = abs(scale) * virial_noise(
                    s.atoms, s.purity, kick.forces(), s.lam_value())
                if guard_band_crossed(y_k, r_k, bound):  # y_k: scratch
                    r_k = round_odd(scale * self.push(clean=True))
            self._r = r_k
            self._key = key
        s.p_lam.add_integers(self._r, float(np.abs(self._r).max()))

    def rollback(self):
        self._key = None

    def adjoint(self, cotangents, ch):
        """``a_rho += c h a_p_lambda dG/d rho``, ``a_lambda += c h
        a_p_lambda dG/d lambda`` (from
        :meth:`~ase_reversible.md.npt.system.ScaledKick.lambda_derivatives`).
        """
        cotangents.flush()
        a = float(cotangents[P_LAMBDA][0])
        if a == 0.0:
            return
        s = self.system
        lam = s.lam_value()
        d_nc, d_s = s.kick.lambda_derivatives()
        cotangents['position'] += (ch * a) * d_nc
        cotangents[LAMBDA] += ch * a * (
            d_s - 6.0 * s.pressure * s.V0 * lam - 2.0 * s.kT / (lam * lam))


def virial_noise(atoms, purity, f_nc, lam):
    """Bound on the history noise of ``lambda**2 V0 tr(sigma) = V
    tr(sigma) / lambda`` (eV) under guarded rounding: a sum over atoms of
    a distance times a force, each below the cell's longest row sum (plus
    the farthest coordinate) times the forces' noise bound."""
    reach = float(np.abs(atoms.cell.array).sum(axis=1).max()) \
        + float(np.abs(atoms.positions).max(initial=0.0))
    return 9.0 * len(atoms) * reach * purity.noise_bound(atoms, f_nc) / lam


def p_lambda_quantum(atoms, purity, spread, max_kick):
    """The quantum of ``p_lambda`` (eV ASE time): ``2**-P_LAMBDA_BITS`` of
    its thermal spread, raised under guarded rounding so that a clean
    recomputation of the stress is needed in at most
    ``TARGET_CLEAN_RATE`` of the piston's kicks of up to ``max_kick``
    (ASE time units)."""
    q = math.ldexp(power_of_two_below(spread), -P_LAMBDA_BITS)
    if purity.mode != 'guarded':
        return q
    # A rounding comes within the bound b (in quanta) of a tie with a
    # chance of about 2b.
    noise = virial_noise(atoms, purity, atoms.get_forces(md=True), 1.0)
    floor = 2.0 * noise * max_kick / TARGET_CLEAN_RATE
    return max(q, math.ldexp(1.0, math.frexp(floor)[1]))


class KineticKick(PistonPush):
    """``p_lambda += round_odd(c h 2K / lambda / q)``, ``2K = sum pi**2 /
    (m lambda**2)``; computed once per value of ``pi`` and ``lambda``."""

    _force = None

    def force(self):
        """The push ``2K / lambda`` (eV)."""
        s = self.system
        lam = s.lam_value()
        return s.momentum_square() / (lam * lam * lam)

    def apply(self, scale):
        s = self.system
        key = (s.p.label, s.lam.label)
        if self._key != key:
            self._force = self.force()
            self._key = key
        s.p_lam.add_rounded(scale * self._force)

    def adjoint(self, cotangents, ch):
        """``a_pi += c h a_p_lambda 2 pi / (m lambda**3)``; ``a_lambda -=
        3 c h a_p_lambda sum pi**2 / (m lambda**4)``."""
        cotangents.flush()
        a = float(cotangents[P_LAMBDA][0])
        if a == 0.0:
            return
        s = self.system
        lam = s.lam_value()
        lam3 = lam * lam * lam
        cotangents[LAMBDA] -= 3.0 * ch * a * s.momentum_square() / (
            lam3 * lam)
        cotangents['momentum'] += (2.0 * ch * a / lam3) * (
            s.p.floats / s.m_n1)


class Piston(SubStep):
    """``lambda += round_odd(c h p_lambda / W / q)``; the atoms then show
    the new positions and cell.  ``lambda`` must stay above
    :data:`LAMBDA_MIN`."""

    def __init__(self, system):
        self.system = system

    def prepare(self, ch):
        s = self.system
        return ch / (s.W * s.lam.quantum)

    def apply(self, factor):
        s = self.system
        s.lam.add_rounded(factor * self.momentum())
        self.refuse_collapse()
        s.show_cell()
        s.show_positions()

    def momentum(self):
        """``p_lambda``, eV ASE time."""
        return float(self.system.p_lam.floats[0])

    def refuse_collapse(self):
        """Raise UnstableIntegrationError if the cell is too small."""
        lam = self.system.lam_value()
        if not lam > LAMBDA_MIN:
            raise UnstableIntegrationError(
                f'The cell collapsed: its linear scale reached {lam:.4g} of '
                f'the construction cell (the volume {lam**3:.3g} of it; at '
                f'most {LAMBDA_MIN**3:.3g} is allowed). The barostat is '
                'unstable or the pressure far too high for this system: '
                'use a larger pdamp, a smaller time step, or a pressure '
                'nearer the system\'s own. The step was not taken; the '
                'state is valid and reversible.')

    def rollback(self):
        s = self.system
        s.show_cell()
        s.show_positions()

    def adjoint(self, cotangents, ch):
        """``a_p_lambda += c h a_lambda / W``."""
        cotangents[P_LAMBDA] += ch / self.system.W * cotangents[LAMBDA]
