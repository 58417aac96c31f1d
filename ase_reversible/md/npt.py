"""ReversibleIsotropicNPT: constant pressure and temperature, run back
exactly.

Andersen's barostat (H. C. Andersen, "Molecular dynamics simulations at
constant pressure and/or temperature", J. Chem. Phys. 72, 2384 (1980)) as
an extended Hamiltonian in scaled variables.  The cell is ``lambda *
cell0`` (``cell0`` the cell at construction, kept in the restart record),
the atoms sit at ``x = lambda * rho`` and carry ``p = pi / lambda``.  The
exact variables are the scaled positions ``rho`` ('position', Å), their
conjugate momenta ``pi = lambda p`` ('momentum'), the linear scale
``lambda`` ('barostat_position', dimensionless) and its momentum
``p_lambda`` ('barostat_momentum', eV ASE time).  The linear scale, not the
volume, is the coordinate: ``V = lambda**3 V0`` then takes multiplications
only, which give the same bits on every CPU (a cube root or a power would
not, see :mod:`ase_reversible.core.portable`).

The Hamiltonian is::

    H = sum pi**2 / (2 m lambda**2) + U(lambda rho, lambda cell0)
        + P V0 lambda**3 + p_lambda**2 / (2 W) - 2 kT ln lambda

The last term makes the invariant measure the isothermal-isobaric one:
with the momenta at temperature ``T``, ``exp(-H / kT)`` integrated over
``p_lambda`` carries the factor ``lambda**2``, and ``lambda**2 d lambda =
dV / (3 V0)``; ``d rho d pi = dx dp`` because the two Jacobians
(``lambda**3N`` and ``lambda**-3N``) cancel.  The stationary density is
then ``exp(-(K + U + P V) / kT) dx dp dV``, the ensemble ASE's MTK
integrators target.

``H`` splits into three parts, each of whose flows is a shear (it adds to
some variables a function of variables it leaves alone), so each is made
exact as the drift and kick of :mod:`.hamiltonian` are:

* ``T = sum pi**2 / (2 m lambda**2)``: ``rho += h pi / (m lambda**2)``
  and ``p_lambda += h 2K / lambda`` (``K`` the kinetic energy);
* ``U + P V - 2 kT ln lambda``: ``pi += h lambda F(x)`` and ``p_lambda +=
  h G`` with ``G = -dU/dlambda - 3 P V0 lambda**2 + 2 kT / lambda``.  At
  fixed ``rho`` a change of ``lambda`` strains the periodic system
  uniformly by ``d lambda / lambda``, and ASE's stress is ``sigma = (1/V)
  dU/d(strain)``, so ``-dU/dlambda = -V tr(sigma) / lambda`` and ``G =
  -lambda**2 V0 (tr(sigma) + 3P) + 2 kT / lambda``
  (``tests/test_npt.py`` checks this against finite differences of the
  energy under a uniform scaling);
* ``p_lambda**2 / (2W)``: ``lambda += h p_lambda / W``.

The temperature is held by Langevin's O step on ``pi`` (whose mass is
``m lambda**2``, ``lambda`` being fixed during it), made exact as in
:mod:`.langevin`: friction through the information buffer, noise from the
counter-based generator.  Its friction is ``1 / tdamp``.  The same O step
gives the piston a friction ``1 / pdamp`` and noise of its own (a Langevin
piston, holding ``p_lambda`` at ``exp(-p_lambda**2 / 2WkT)``, which leaves
the ensemble as it is): it decorrelates the volume sooner.  Measured on
256 Cu atoms (asap3 EMT, 300 K, P = 0, dt 5 fs, tdamp 100 fs, pdamp 500
fs, two seeds of 20,000 steps each, the first 2,000 left out): the
volume oscillates with a period of 19 steps under either; the envelope of
its autocorrelation falls below 1/e after 180 steps without the piston's
friction and after 100-120 with it, and the sum of the squared
autocorrelation over 1,000 lags is 42-50 without and 26-30 with, at the
same spread of the volume (9.8-10.5 Å**3 of 3022).  Its deviate is drawn
with the atoms' (a draw of its own would cost 120 us a step; with the
atoms', the piston's part of the O step costs 30 us, timeit on 32 atoms
under load 4.5).  One step is the palindrome ``B/2 P/2 T/2 O T/2 P/2 B/2``
(B the ``U`` part, P the piston, T the kinetic part), with one force and
stress call, at the step's end as in velocity Verlet.

The barostat's mass.  ASE's ``IsotropicMTKNPT`` moves ``eps = ln(V/V0) / 3
= ln lambda`` with the mass ``W_eps = (3N + 3) kT pdamp**2``, so that the
volume oscillates with a period of the order of ``pdamp``.  The kinetic
energy ``W_eps (d eps/dt)**2 / 2 = W_eps (d lambda/dt)**2 / (2 lambda**2)``
equals ``W (d lambda/dt)**2 / 2`` at the construction volume for ``W =
W_eps``: that is the ``W`` used (``lambda`` stays near 1, the volume
moving by a few per cent).

Only fully periodic cells are supported: for a cluster ``-dU/dlambda``
would be the virial ``sum x.F / lambda``, and ``V`` has no meaning.

Gradients.  Each sub-step has its adjoint rule.  The piston's push ``G``
needs its derivative in ``rho``, the stress's derivative in the
positions, which no calculator offers; but ``dG/d rho = -d2U/(d rho d
lambda) = d(lambda F)/d lambda``, so it is the central difference of
``lambda F`` in ``lambda`` (positions and cell scaled together), which
also gives the kick's derivative in ``lambda``; the same two calls give
``dG/d lambda`` from the stress.  The O step's noise scales with
``lambda``: its derivative ``n`` (the noise at ``lambda = 1``) enters
``a_lambda``.  The friction's rounding (the buffer's digits) is left out,
as for :class:`~ase_reversible.ReversibleLangevin`.
"""

from __future__ import annotations

import hashlib
import math
import warnings

import numpy as np
from ase import units
from ase.calculators.calculator import PropertyNotImplementedError

from ..core.codec import encode, round_odd
from ..core.compositions import composition_for
from ..adjoint.hessian import DEFAULT_FD_STEP
from ..core.engine import Engine, InvariantCheck
from ..core.portable import dot
from ..core.infobuffer import BufferUnderflowError, InformationBuffer
from ..core.noise import StepNoise
from ..core.plans import SubStep
from ..core.record import read_record
from ..core.variables import ExactVariable
from ..purity.settings import TARGET_CLEAN_RATE
from ..errors import (AnchorMovedWarning, RetraceLimitError,
                      UnstableIntegrationError, UnsupportedConstraintError)
from .base import ReversibleDynamics
from .checks import check_energy_watch, check_timestep, fixed
from .hamiltonian import Drift, Hamiltonian, Kick, largest_kick
from .langevin import (Friction, _checked_friction, _checked_positive,
                       _checked_seed, exact_ratio)
from .watch import SystemWatch

LAMBDA, P_LAMBDA = 'barostat_position', 'barostat_momentum'
KICK, VIRIAL, PISTON, DRIFT, KINETIC, FRICTION = (
    'kick', 'virial', 'piston', 'drift', 'kinetic', 'friction')

#: ``B/2 P/2 T/2 O T/2 P/2 B/2`` (module docstring): a palindrome, so the
#: same sequence run with -h undoes a step.  The two parts of B read
#: ``rho`` and ``lambda`` only, the two of T ``pi`` and ``lambda`` only.
SCHEME = ((KICK, 0.5), (VIRIAL, 0.5), (PISTON, 0.5), (DRIFT, 0.5),
          (KINETIC, 0.5), (FRICTION, 1.0), (KINETIC, 0.5), (DRIFT, 0.5),
          (PISTON, 0.5), (VIRIAL, 0.5), (KICK, 0.5))

#: Whether the piston has friction ``1 / pdamp`` and noise of its own (a
#: Langevin piston).
PISTON_FRICTION = True

#: Default steps between checks of the energy balance.
ENERGY_CHECK_INTERVAL = 100

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

#: What ASE's chain integrators take and this class has no use for.
_ASE_ONLY = {
    'tchain': 'the thermostat is Langevin friction and noise on every '
              'momentum (no chain): leave tchain out',
    'pchain': 'the barostat is one piston, thermalised through the atoms '
              '(no chain): leave pchain out',
    'tloop': 'the thermostat is one exact O step per time step: leave '
             'tloop out',
    'ploop': 'the piston moves in two exact half steps per time step: '
             'leave ploop out',
    'rng': 'the noise comes from a counter-based generator the way back '
           'can draw again: pass seed=<int> instead of rng',
}


def _power_of_two_below(value):
    return math.ldexp(1.0, math.frexp(value)[1] - 1)


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
        self.W = barostat_mass(len(self.m_n1), self.kT, pdamp)

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
        key = (self.p.label, self.lam.label)
        if self._shown_key != key:
            np.divide(self.p.floats, self.lam_value(), out=self._shown_nc)
            self._shown_key = key
        return self._shown_nc

    def show_momenta(self):
        momenta = self.atoms.arrays.get('momenta')
        if momenta is None:
            self.atoms.set_momenta(self.shown_momenta(),
                                   apply_constraint=False)
        else:
            np.copyto(momenta, self.shown_momenta())

    def show(self):
        self.show_cell()
        super().show()

    def counts_of(self, positions_nc, momenta_nc, lam):
        """``(rho, pi)`` counts (int64) of shown positions and momenta at
        ``lambda = lam``."""
        return (encode(positions_nc / lam, self.x.quantum, 'position'),
                encode(momenta_nc * lam, self.p.quantum, 'momentum'))

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

    def stress_trace(self):
        """``tr(sigma)`` (eV/Å**3, ASE's sign) at the shown positions and
        cell, from the call that gave the forces."""
        key = self._key()
        if self._stress is not None and self._stress[0] == key:
            return self._stress[1]
        self.forces()
        sigma = self.system.atoms.get_stress(voigt=True,
                                             apply_constraint=False)
        trace = float(sigma[0]) + float(sigma[1]) + float(sigma[2])
        self._stress = (key, trace)
        return trace

    def clean_stress_trace(self):
        """``tr(sigma)`` from a neighbour list built at exactly these
        positions (guarded rounding's clean recomputation)."""
        s = self.system
        f_nc = s.purity.clean_forces(s.atoms)
        self._f_cache = (self._key(), f_nc)
        sigma = s.atoms.get_stress(voigt=True, apply_constraint=False)
        trace = float(sigma[0]) + float(sigma[1]) + float(sigma[2])
        self._stress = (self._key(), trace)
        return trace

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


def _add_rounded(variable, y):
    """Add ``round_odd(y)`` (a float, in quanta) to a variable of shape
    ``[1]``."""
    r = np.array([y])
    round_odd(r, out=r)
    variable.add_integers(r, abs(float(r[0])))


class VirialKick(SubStep):
    """``p_lambda += round_odd(c h G / q)``, ``G = -lambda**2 V0 (tr(sigma)
    + 3P) + 2 kT / lambda`` (module docstring).

    Under guarded rounding the increment is a rounding like the kick's: if
    it lies within the stress's noise bound of a tie, the stress is
    recomputed from a clean neighbour list.  The rounded increment is kept
    for the next half step at the same positions and cell.
    """

    def __init__(self, system):
        self.system = system
        self._key = self._r = None

    def prepare(self, ch):
        return ch / self.system.p_lam.quantum

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
            y = scale * self.force(kick.stress_trace())
            if s.purity.mode == 'guarded' and not kick.stress_is_clean():
                bound = abs(scale) * virial_noise(s.atoms, s.purity,
                                                  kick.forces(),
                                                  s.lam_value())
                if abs(y - round_odd(y)) > 0.5 - bound:
                    y = scale * self.force(kick.clean_stress_trace())
            self._r = np.array([round_odd(y)])
            self._key = key
        s.p_lam.add_integers(self._r, abs(float(self._r[0])))

    def rollback(self):
        self._key = None

    def adjoint(self, cotangents, ch):
        """``a_rho += c h a_p_lambda dG/d rho``, ``a_lambda += c h
        a_p_lambda dG/d lambda`` (:meth:`ScaledKick.lambda_derivatives`)."""
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
    q = math.ldexp(_power_of_two_below(spread), -P_LAMBDA_BITS)
    if purity.mode != 'guarded':
        return q
    # A rounding comes within the bound b (in quanta) of a tie with a
    # chance of about 2b.
    noise = virial_noise(atoms, purity, atoms.get_forces(md=True), 1.0)
    floor = 2.0 * noise * max_kick / TARGET_CLEAN_RATE
    return max(q, math.ldexp(1.0, math.frexp(floor)[1]))


class KineticKick(SubStep):
    """``p_lambda += round_odd(c h 2K / lambda / q)``, ``2K = sum pi**2 /
    (m lambda**2)``; computed once per value of ``pi`` and ``lambda``."""

    def __init__(self, system):
        self.system = system
        self._key = self._force = None

    def prepare(self, ch):
        return ch / self.system.p_lam.quantum

    def apply(self, scale):
        s = self.system
        key = (s.p.label, s.lam.label)
        if self._key != key:
            lam = s.lam_value()
            self._force = s.momentum_square() / (lam * lam * lam)
            self._key = key
        _add_rounded(s.p_lam, scale * self._force)

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
        _add_rounded(s.lam, factor * float(s.p_lam.floats[0]))
        lam = s.lam_value()
        if not lam > LAMBDA_MIN:
            raise UnstableIntegrationError(
                f'The cell collapsed: its linear scale reached {lam:.4g} of '
                f'the construction cell (the volume {lam**3:.3g} of it; at '
                f'most {LAMBDA_MIN**3:.3g} is allowed). The barostat is '
                'unstable or the pressure far too high for this system: '
                'use a larger pdamp, a smaller time step, or a pressure '
                'nearer the system\'s own. The step was not taken; the '
                'state is valid and reversible.')
        s.show_cell()
        s.show_positions()

    def rollback(self):
        s = self.system
        s.show_cell()
        s.show_positions()

    def adjoint(self, cotangents, ch):
        """``a_p_lambda += c h a_lambda / W``."""
        cotangents[P_LAMBDA] += ch / self.system.W * cotangents[LAMBDA]


class ScaledFriction(Friction):
    """Langevin's exact O step on ``pi``, whose mass is ``m lambda**2``:
    the noise's spread is ``lambda`` times that for the mass ``m``, and
    the heat it adds is measured with ``1 / (m lambda**2)``.  With a
    :class:`PistonFriction` (``piston``), the same step also applies it
    to ``p_lambda``."""

    def __init__(self, system, settings, step_of, piston=None):
        super().__init__(system, settings, step_of)
        self.piston = piston
        if piston is not None:
            # The piston's deviate comes from the atoms' draw: a draw costs
            # 120 us however few deviates it makes (one deviate, timeit,
            # load 4.5), so a draw of its own would add that to a step.
            self.noise = _OneMoreNormal(self.noise.size)

    def prepare(self, ch):
        return (super().prepare(ch),
                None if self.piston is None else self.piston.prepare(ch))

    def apply(self, prepared):
        atoms_part, piston_part = prepared
        lam = self.system.lam_value()
        parts = list(atoms_part)
        parts[3] = atoms_part[3] * lam
        parts[6] = atoms_part[6] / (lam * lam)
        super().apply(tuple(parts))
        if piston_part is not None:
            self.piston.apply(piston_part, self.noise.extra)

    def forget(self):
        super().forget()
        if self.piston is not None:
            self.piston.forget()

    def active_buffers(self):
        """The atoms' buffers that hold digits, by friction ratio ``n``
        (the piston's: ``piston.active_buffers()``)."""
        return super().active_buffers()

    def checkpoint(self):
        super().checkpoint()
        if self.piston is not None:
            self.piston.checkpoint()

    def rollback(self):
        super().rollback()
        if self.piston is not None:
            self.piston.rollback()

    def adjoint(self, cotangents, ch):
        """``pi' = c pi + lambda n`` (``n`` the noise for the mass ``m``,
        the same both ways): ``a_lambda += a_pi' . n``, then ``a_pi = c
        a_pi'``; the piston's ``a_p_lambda *= c_piston``."""
        cotangents.flush()
        s = self.system
        atoms_part, piston_part = self.prepare(ch)
        sigma_k, key, zero_sum = atoms_part[3], atoms_part[4], atoms_part[5]
        n_k = s.p.quantum * sigma_k * self.noise.normals(key, self.step_of())
        n_nc = n_k.reshape(self.shape)
        if zero_sum is not None:
            n_nc = n_nc - zero_sum[0] * n_nc.sum(axis=0)
        cotangents[LAMBDA] += dot(cotangents['momentum'], n_nc)
        cotangents['momentum'] *= exact_ratio(self.settings()[0], ch)[1]
        if piston_part is not None:
            cotangents[P_LAMBDA] *= exact_ratio(self.piston.friction, ch)[1]


class _OneMoreNormal(StepNoise):
    """The atoms' deviates of a step, drawn together with one more, kept
    as :attr:`extra` for the piston."""

    def __init__(self, size):
        super().__init__(size + 1)
        self.extra = None

    def normals(self, key, step):
        z = super().normals(key, step)
        self.extra = float(z[-1])
        return z[:-1]


class PistonFriction:
    """The O step on ``p_lambda`` (a Langevin piston): ``p_lambda <- c
    p_lambda + sqrt((1 - c**2) W kT) xi``, exact as the atoms' (the
    friction through an information buffer of one coordinate, the
    deviate ``xi`` drawn with the atoms' by the counter-based generator).

    Parameters
    ----------
    system : NPTHamiltonian
    friction : float
        1 / ASE time unit (``1 / pdamp``).
    """

    def __init__(self, system, friction):
        self.system = system
        self.friction = friction
        self.buffers = {}
        self.heat = self._saved_heat = 0.0

    def forget(self):
        """Empty the buffers and zero the heat: the anchor moved here."""
        for buffer in self.buffers.values():
            buffer.clear()
        self.heat = self._saved_heat = 0.0

    def active_buffers(self):
        """The buffers that hold digits, by friction ratio ``n``."""
        return {n: b for n, b in self.buffers.items() if not b.is_empty()}

    def prepare(self, ch):
        """What :meth:`apply` needs at the coefficient ``ch``."""
        s = self.system
        n, ratio = exact_ratio(self.friction, ch)
        buffer = self.buffers.get(n)
        if buffer is None:
            buffer = self.buffers[n] = InformationBuffer(1, n)
        sigma = math.sqrt((1.0 - ratio * ratio) * s.W * s.kT) \
            / s.p_lam.quantum
        return ch > 0, buffer, sigma

    def apply(self, prepared, xi):
        """One O step of ``p_lambda`` with the standard normal deviate
        ``xi``."""
        forward, buffer, sigma = prepared
        p = self.system.p_lam
        x_k = p.ints.reshape(-1)
        noise_k = np.array([np.rint(sigma * xi)], dtype=np.int64)
        if forward:
            new_k = buffer.scale_down(x_k) + noise_k
        else:
            try:
                new_k = buffer.scale_up(x_k - noise_k)
            except BufferUnderflowError:
                raise RetraceLimitError(
                    'ReversibleIsotropicNPT can only retrace steps it has '
                    'taken: this one goes back past the anchor of '
                    'reversal, where the piston\'s friction would have to '
                    'be undone that was never applied. The step was not '
                    'taken; run forward (positive dt) from here.') from None
        q = p.quantum
        old, new = float(x_k[0]) * q, float(new_k[0]) * q
        self.heat += 0.5 * (new * new - old * old) / self.system.W
        p.add_integers((new_k - x_k).astype(np.float64))

    def checkpoint(self):
        """Remember the heat and the buffers."""
        self._saved_heat = self.heat
        for buffer in self.buffers.values():
            buffer.checkpoint()

    def rollback(self):
        """Back to the last :meth:`checkpoint`."""
        self.heat = self._saved_heat
        for buffer in self.buffers.values():
            buffer.rollback()


def _digest(counts):
    h = hashlib.sha256()
    for name in sorted(counts):
        h.update(np.ascontiguousarray(counts[name], dtype=np.int64).tobytes())
    return h.hexdigest()


class ReversibleIsotropicNPT(ReversibleDynamics):
    """Constant pressure and temperature (NPT) in fixed point, run back
    exactly: the counterpart of ASE's
    :class:`ase.md.nose_hoover_chain.IsotropicMTKNPT`.

    The cell is scaled uniformly by an exact piston (Andersen's barostat)
    and the atoms are held at ``temperature_K`` by Langevin friction and
    noise (module docstring).  After ``run(n)``, :meth:`reverse` and
    ``run(n)``, the scaled positions, their momenta, the cell's scale and
    its momentum and the information buffer are bitwise those right after
    the constructor; so are ``atoms.positions``, ``atoms.get_momenta()``
    and ``atoms.cell``.  The atoms show the Cartesian positions, momenta
    and cell after every step observers see, so ``atoms.get_volume()``,
    ``atoms.get_temperature()`` and trajectories work as with ASE's NPT.

    Parameters
    ----------
    atoms : ase.Atoms
        Periodic in all three directions, with a calculator that gives
        the stress (ASE's EMT and LennardJones, asap3's, this package's
        LennardJones).  No constraints.
    timestep : float
        ASE time units (``2 * ase.units.fs``).
    temperature_K : float
        Target temperature, K.
    pressure_au : float
        Target pressure, eV/Å**3 (``1.0 * ase.units.GPa``), as ASE's.
    tdamp : float
        The thermostat's time, ASE time units (``100 * timestep`` is
        common): the Langevin friction is ``1 / tdamp``.
    pdamp : float
        The barostat's time, ASE time units (``1000 * timestep`` is
        common): the piston's mass is ASE's MTK mass ``(3N + 3) kT
        pdamp**2``, so the volume oscillates with a period of the order
        of ``pdamp``.
    seed : int, optional
        Key of the thermostat's noise.  Default: the seed of the atoms'
        restart record if it was written at this time step, else drawn
        from the operating system.
    buffer : str or path, optional
        A file :meth:`write_buffer` wrote with the frame these atoms come
        from: the run then goes on bit for bit as the one that wrote it,
        and runs back past this point.
    trajectory, logfile, loginterval
        As for :class:`ase.md.verlet.VelocityVerlet`.
    position_quantum, momentum_quantum, force_purity, force_noise
        As for :class:`~ase_reversible.ReversibleVerlet` (the position
        quantum is that of the scaled positions, Å at the construction
        cell; the momentum quantum that of ``pi``).
    energy_check : int
        As for :class:`~ase_reversible.ReversibleVerlet`, for
        :meth:`get_conserved_energy`.
    energy_tolerance : float, optional
        eV; default as for :class:`~ase_reversible.ReversibleVerlet`.
    **kwargs
        Passed to :class:`ase.md.md.MolecularDynamics`.

    ASE's ``tchain``, ``pchain``, ``tloop``, ``ploop`` and ``rng`` are
    refused with a TypeError that says what to pass instead.

    Raises
    ------
    TypeError
        An argument of ASE's chain integrators, or bad argument types.
    ValueError
        A non-periodic cell, a calculator without stress, non-positive
        temperature, tdamp or pdamp, a negative pressure... (before
        anything is changed).
    UnsupportedConstraintError
        Any constraint.
    UnstableIntegrationError
        During a run: the cell collapsed (``lambda`` below
        :data:`LAMBDA_MIN`) or the conserved energy drifted; the step was
        not taken, and the state runs back exactly.
    """

    record_sections = ('npt',)

    def __init__(self, atoms, timestep, temperature_K, pressure_au, tdamp,
                 pdamp, *, seed=None, buffer=None, trajectory=None,
                 logfile=None, loginterval=1, position_quantum=None,
                 momentum_quantum=None, force_purity='auto',
                 force_noise=None, energy_check=ENERGY_CHECK_INTERVAL,
                 energy_tolerance=None, **kwargs):
        for name, advice in _ASE_ONLY.items():
            if name in kwargs:
                raise TypeError(
                    f'ReversibleIsotropicNPT takes no {name} (an argument of '
                    f'ASE\'s IsotropicMTKNPT): {advice}.')
        timestep = check_timestep(timestep)
        temperature_K = _checked_positive(temperature_K, 'temperature_K',
                                          'K')
        pressure_au = _checked_pressure(pressure_au)
        tdamp = _checked_positive(tdamp, 'tdamp', 'ASE time units, e.g. '
                                  '100 * ase.units.fs')
        pdamp = _checked_positive(pdamp, 'pdamp', 'ASE time units, e.g. '
                                  '1000 * ase.units.fs')
        friction = _checked_friction(1.0 / tdamp, timestep)
        energy_check, energy_tolerance = check_energy_watch(
            energy_check, energy_tolerance)
        _refuse_cell(atoms)
        _refuse_constraints(atoms)
        system, record = self._hamiltonian(
            atoms, largest_kick(SCHEME, composition_for(2, None), timestep,
                                KICK),
            position_quantum, momentum_quantum, force_purity, force_noise,
            system_class=NPTHamiltonian)
        _refuse_stressless(atoms)
        kT = units.kB * temperature_K
        spread = math.sqrt(barostat_mass(len(atoms), kT, pdamp) * kT)
        quanta = {LAMBDA: LAMBDA_QUANTUM,
                  P_LAMBDA: p_lambda_quantum(
                      atoms, system.purity, spread,
                      largest_kick(SCHEME, composition_for(2, None),
                                   timestep, VIRIAL))}
        cell0, counts, section = self._barostat_start(system, record,
                                                      quanta)
        system.set_barostat(cell0, counts, quanta, temperature_K,
                            pressure_au, tdamp, pdamp)
        if section is not None:
            section = self._resume_scaled(system, section)
        if section is None and record is not None:
            record = None  # a new run: time from 0
        self._friction = friction
        resumed = _resumed_noise(section, timestep)
        if seed is None and resumed is not None:
            seed = resumed['seed']
        self._seed = _checked_seed(seed)
        step = resumed['step'] if resumed is not None else 0
        piston = PistonFriction(system, _checked_friction(
            1.0 / pdamp, timestep)) if PISTON_FRICTION else None
        friction_step = ScaledFriction(
            system, lambda: (friction, system.temperature_K, True, self._seed),
            self._step_of, piston)
        substep = {KICK: system.kick, VIRIAL: VirialKick(system),
                   PISTON: Piston(system), DRIFT: system.drift,
                   KINETIC: KineticKick(system), FRICTION: friction_step}
        invariant = InvariantCheck(
            energy_check, energy_tolerance, self._balance,
            self._explain_drift, trigger=self._balance_trigger)
        engine = Engine(system.variables,
                        tuple((substep[k], c) for k, c in SCHEME),
                        composition_for(2, None), timestep,
                        invariant=invariant)
        self.friction_step = friction_step
        engine.step_index = engine.anchor_index = step
        saved = None if buffer is None else self._read_buffer(
            buffer, system, timestep, step)
        if saved is not None:
            engine.anchor_index = int(saved['anchor_step'])
            engine.anchor = {name: saved[f'anchor_{name}']
                             for name in engine.variables}
            friction_step.load(saved)
            _load_piston(friction_step.piston, saved)
        time0 = record['time'] - engine.elapsed() if record else 0.0
        self._attach(system, engine, (force_purity, force_noise), time0)
        system.show_cell()
        super().__init__(atoms, timestep, trajectory=trajectory,
                         logfile=logfile, loginterval=loginterval, **kwargs)
        self._start(SystemWatch(atoms))

    # -- construction -------------------------------------------------------

    def _resumable_record(self, atoms):
        # A frame of this class shows positions and momenta off the grid
        # (lambda rho, pi / lambda): its record is checked when rho and pi
        # are recovered (_resume_scaled).
        record = read_record(atoms.info,
                             sections=(*self.record_sections, 'machine'))
        if record is not None and record.get('npt') is not None:
            self._resumed_machine = record.get('machine')
            return record
        return super()._resumable_record(atoms)

    @staticmethod
    def _barostat_start(system, record, quanta):
        """``(cell0, counts, section)``: from the record's ``'npt'``
        section if it has a valid one (``quanta`` then take its quanta),
        else the atoms' cell, ``lambda = 1`` and ``p_lambda = 0``."""
        atoms = system.atoms
        counts = {LAMBDA: np.array([round(1.0 / LAMBDA_QUANTUM)], np.int64),
                  P_LAMBDA: np.zeros(1, np.int64)}
        section = record.get('npt') if record else None
        if section is not None:
            saved = read_record(atoms.info, names=(LAMBDA, P_LAMBDA))
            try:
                lam_count = int(section[LAMBDA])
                p_count = int(section[P_LAMBDA])
                cell0 = np.array(section['cell0'], dtype=float).reshape(3, 3)
            except (KeyError, TypeError, ValueError):
                saved = None
            if saved is not None and lam_count > 0 and np.isfinite(
                    cell0).all() and np.array_equal(
                        cell0 * (lam_count * saved[f'{LAMBDA}_quantum']),
                        atoms.cell.array):
                quanta[LAMBDA] = saved[f'{LAMBDA}_quantum']
                quanta[P_LAMBDA] = saved[f'{P_LAMBDA}_quantum']
                counts[LAMBDA][0], counts[P_LAMBDA][0] = lam_count, p_count
                return cell0, counts, section
            _warn_new_run('the cell or its record was changed since the '
                          'frame was written')
        return atoms.cell.array.copy(), counts, None

    def _resume_scaled(self, system, section):
        """Set ``rho`` and ``pi`` from a frame: stored in the record, or
        recovered from ``x / lambda`` and ``p lambda``, and checked to
        show the frame again bit for bit.  Returns the section, or None
        (and starts afresh) if the frame was edited."""
        atoms = system.atoms
        lam = system.lam_value()
        momenta = atoms.arrays.get('momenta')
        if momenta is None:
            momenta = np.zeros((len(atoms), 3))
        try:
            rho, pi = system.counts_of(atoms.positions, momenta, lam)
        except Exception:
            rho = pi = None
        if 'position' in section:
            rho = np.array(section['position'], np.int64).reshape(-1, 3)
        if 'momentum' in section:
            pi = np.array(section['momentum'], np.int64).reshape(-1, 3)
        if rho is not None and pi is not None \
                and rho.shape == system.x.ints.shape \
                and pi.shape == system.p.ints.shape:
            system.x.reset(rho)
            system.p.reset(pi)
            if np.array_equal(system.shown_positions(), atoms.positions) \
                    and np.array_equal(system.shown_momenta(), momenta):
                return section
        _warn_new_run('the positions or momenta were changed since the '
                      'frame was written')
        cell0 = atoms.cell.array.copy()
        rho, pi = system.counts_of(atoms.positions, momenta, 1.0)
        system.x.reset(rho)
        system.p.reset(pi)
        quanta = {LAMBDA: system.lam.quantum, P_LAMBDA: system.p_lam.quantum}
        system.set_barostat(
            cell0, {LAMBDA: np.array([round(1.0 / system.lam.quantum)]),
                    P_LAMBDA: np.zeros(1, np.int64)}, quanta,
            system.temperature_K, system.pressure, system.tdamp,
            system.pdamp)
        return None

    def _read_buffer(self, path, system, timestep, step):
        with np.load(path) as f:
            saved = {key: f[key] for key in f.files}
        problems = []
        if int(saved['seed']) != self._seed:
            problems.append(f'it was written with seed {int(saved["seed"])}, '
                            f'not {self._seed}')
        if float(saved['timestep']) != abs(timestep):
            problems.append('it was written at a time step of '
                            f'{float(saved["timestep"]) / units.fs:g} fs')
        state = {name: v.ints for name, v in system.variables.items()}
        if int(saved['step']) != step or str(saved['digest']) != \
                _digest(state):
            problems.append(f'it was written at step {int(saved["step"])} '
                            'of another state')
        if problems:
            raise ValueError(
                f'The buffer file {path} does not belong to these atoms: '
                + '; '.join(problems) + '. Pass the frame written together '
                'with it, or no buffer to go on without the way back.')
        return saved

    def write_buffer(self, path):
        """Write what reversal through this point needs to ``path`` (NumPy
        ``.npz``), as :meth:`ase_reversible.ReversibleLangevin.write_buffer`
        does: a frame written now and this file restart the run bit for
        bit (``ReversibleIsotropicNPT(frame, ..., buffer=path)``), and
        the restarted run goes back past the restart point."""
        self._sync()
        engine = self.engine
        if engine.other_step_sizes:
            raise ValueError(
                'Steps with another time step are on the way back to the '
                'anchor; write the buffer after retracing them, or from a '
                'run at one time step.')
        arrays = {'seed': np.uint64(self._seed), 'timestep': abs(engine.dt),
                  'step': engine.step_index,
                  'anchor_step': engine.anchor_index,
                  'digest': _digest(engine.snapshot())}
        for name, counts in engine.anchor.items():
            arrays[f'anchor_{name}'] = counts
        piston = self.friction_step.piston
        for prefix, buffers in (
                ('buffer', self.friction_step.active_buffers()),
                ('piston', {} if piston is None else
                 piston.active_buffers())):
            for n, b in buffers.items():
                depth = int(b.top_k.max(initial=0))
                arrays[f'{prefix}_{n}_state'] = b.state_k
                arrays[f'{prefix}_{n}_top'] = b.top_k
                arrays[f'{prefix}_{n}_words'] = b.words_jk[:depth]
        with open(path, 'wb') as f:
            np.savez(f, **arrays)

    # -- what the steps read ------------------------------------------------

    def _step_of(self):
        engine = self.engine
        return engine.step_index if engine.direction > 0 \
            else engine.step_index - 1

    def _balance(self):
        energy, proposed = self.system.energy()
        return (energy + self.system.barostat_energy() - self.heat,
                proposed)

    def _balance_trigger(self):
        system = self.system
        return (system.kinetic_energy() + system.barostat_energy()
                - self.heat)

    def _explain_drift(self, number, drift, tolerance):
        return (
            f'The conserved energy (atoms, P V and the piston, less the heat '
            f'the thermostat added) has changed by {drift:.4g} eV since the '
            f'anchor of reversal (tolerance {tolerance:.4g} eV) after step '
            f'{number}: the integration is unstable. Use a smaller time '
            f'step (now {abs(self.dt) / units.fs:g} fs) or a larger pdamp '
            f'(now {self.pdamp / units.fs:g} fs). The step was not taken; '
            'the state is valid and reverse() leads back exactly. If the '
            'change is expected, raise energy_tolerance or pass '
            'energy_check=0.')

    def _ready(self):
        self.system.kick.forces()

    def _record_sections(self):
        system, engine = self.system, self.engine
        section = {LAMBDA: int(system.lam.ints[0]),
                   P_LAMBDA: int(system.p_lam.ints[0]),
                   'cell0': system.cell0.reshape(-1).tolist(),
                   'temperature_K': system.temperature_K,
                   'pressure_au': system.pressure, 'tdamp': system.tdamp,
                   'pdamp': system.pdamp, 'seed': self._seed,
                   'step': engine.step_index, 'timestep': abs(engine.dt)}
        if not system.x.bound < RECOVERABLE:
            section['position'] = system.x.ints.reshape(-1).tolist()
        if not system.p.bound < RECOVERABLE:
            section['momentum'] = system.p.ints.reshape(-1).tolist()
        return {'npt': section}

    # -- changes made around the run ---------------------------------------

    def _shown_positions(self):
        return self.system.shown_positions()

    def _sync(self):
        # The cell this class moved is no change; any other is.
        # On the per-step path where code may run between the steps
        # (observers, irun): 0.2 us (32 Cu atoms, timeit under load 4.5),
        # as the cell is compared by its bytes, kept when shown (1 us, two
        # a step).
        atoms = self.atoms
        if atoms.cell.array.tobytes() == self.system.shown_cell_bytes:
            self._watch.accept_cell(atoms)
        super()._sync()

    def _take_changes(self, changes):
        atoms, system = self.atoms, self.system
        if 'the cell' in changes or 'pbc' in changes:
            cell = atoms.cell.array.copy()
            atoms.pbc = True
            system.show()
            self._watch.accept_cell(atoms)
            raise ValueError(
                'The cell (or pbc) was changed outside '
                'ReversibleIsotropicNPT, which moves the cell itself (to '
                f'{cell.tolist()}): the change is refused. The cell, '
                'positions and momenta were put back to the exact state '
                f'at time {self.get_time() / units.fs:.6g} fs, from which '
                'reverse() and further runs go on. To start from another '
                'cell, construct a new ReversibleIsotropicNPT.')
        _refuse_constraints(atoms)
        if atoms.calc is not None and atoms.calc is not self._watch.calc:
            _refuse_stressless(atoms)
        return super()._take_changes(changes)

    def _encode(self, atoms, project):
        system = self.system
        lam = system.lam_value()
        momenta = atoms.arrays.get('momenta')
        if momenta is None:
            momenta = np.zeros((len(atoms), 3))
        rho, pi = system.counts_of(atoms.positions, momenta, lam)
        return {'position': rho, 'momentum': pi,
                LAMBDA: system.lam.ints, P_LAMBDA: system.p_lam.ints}

    def _install(self, counts):
        # Steps before the new anchor cannot be retraced: their digits go.
        self.friction_step.forget()
        super()._install(counts)
        self.system.show_cell()

    # -- gradients ----------------------------------------------------------

    #: The labels of the state the last backpropagate ended at.
    _retrace_end = None

    def backpropagate(self, steps, grad_positions=None, grad_momenta=None,
                      *, hvp='auto', parameters=(), carry=None, loss=None,
                      every=1, window=None):
        """Gradients of a loss with respect to the state ``steps`` steps
        ago, as for :meth:`ase_reversible.ReversibleLangevin.backpropagate`
        (the atoms' positions and momenta, at a fixed scale of the cell).

        The returned :class:`~ase_reversible.Gradients` has in
        ``.thermostat`` the gradients with respect to the barostat's
        ``'lambda'`` (at fixed positions and momenta) and ``'p_lambda'``.
        Each step of the retrace costs, besides the product of each kick,
        two calls for forces and stress (the derivatives in ``lambda`` by
        central differences).  Potential parameters are not offered: the
        piston would need the stress's derivative with respect to them.
        """
        if parameters:
            raise NotImplementedError(
                'ReversibleIsotropicNPT gives no gradients with respect to '
                'potential parameters: the piston would need the '
                "stress's derivative with respect to them. Use "
                'parameters=() here, or a fixed-cell run.')
        return super().backpropagate(
            steps, grad_positions, grad_momenta, hvp=hvp, carry=carry,
            loss=loss, every=every, window=window)

    def _cotangents_of(self, ax_nc, ap_nc, carry):
        # The user's gradients are on (x, p) at fixed (lambda, p_lambda);
        # the exact variables are (rho, pi, lambda, p_lambda) with x =
        # lambda rho and p = pi / lambda.
        here = self._retrace_key()
        if carry is None and here == self._retrace_end:
            raise ValueError(
                'The atoms are where the last backpropagate ended. To go on '
                'with a loss on several states, pass what it returned as '
                'carry= (the barostat carries part of the gradient from one '
                'segment to the next); to start a new loss here, pass '
                'carry=False.')
        if carry and here != self._retrace_end:
            raise ValueError(
                'carry= goes on from where the last backpropagate ended, '
                'but the state has changed since: pass carry=False or none.')
        barostat = carry.thermostat if carry else {}
        added = self._loss_cotangents(ax_nc, ap_nc)
        return {'position': added['position'],
                'momentum': added['momentum'],
                LAMBDA: added[LAMBDA] + float(barostat.get('lambda', 0.0)),
                P_LAMBDA: np.array([float(barostat.get('p_lambda', 0.0))])}

    def _loss_cotangents(self, ax_nc, ap_nc):
        s = self.system
        lam = s.lam_value()
        n = s.x.ints.shape
        ax_nc = np.zeros(n) if ax_nc is None else np.asarray(ax_nc, float)
        ap_nc = np.zeros(n) if ap_nc is None else np.asarray(ap_nc, float)
        return {'position': lam * ax_nc, 'momentum': ap_nc / lam,
                LAMBDA: np.array([dot(ax_nc, s.x.floats)
                                  - dot(ap_nc, s.p.floats) / (lam * lam)])}

    def _gradients_of(self, cotangents):
        # Back to (x, p) at fixed lambda: dL/dx = a_rho / lambda, dL/dp =
        # lambda a_pi, and dL/dlambda at fixed (x, p) = a_lambda - a_rho .
        # rho / lambda + a_pi . pi / lambda.
        s = self.system
        lam = s.lam_value()
        a_rho, a_pi = cotangents['position'], cotangents['momentum']
        a_lam = (float(cotangents[LAMBDA][0]) - dot(a_rho, s.x.floats) / lam
                 + dot(a_pi, s.p.floats) / lam)
        self._retrace_end = self._retrace_key()
        return (a_rho / lam, a_pi * lam,
                {'lambda': a_lam, 'p_lambda': float(cotangents[P_LAMBDA][0])})

    def _retrace_key(self):
        return tuple(v.label for v in self.system.variables.values())

    # -- the ensemble --------------------------------------------------------

    @property
    def temperature_K(self) -> float:
        """Target temperature, K (fixed at construction)."""
        return self.system.temperature_K

    @property
    def pressure_au(self) -> float:
        """Target pressure, eV/Å**3 (fixed at construction)."""
        return self.system.pressure

    @property
    def tdamp(self) -> float:
        """The thermostat's time, ASE time units (friction ``1 / tdamp``)."""
        return self.system.tdamp

    @property
    def pdamp(self) -> float:
        """The barostat's time, ASE time units."""
        return self.system.pdamp

    @temperature_K.setter
    def temperature_K(self, value):
        fixed('temperature_K')

    @pressure_au.setter
    def pressure_au(self, value):
        fixed('pressure_au')

    @tdamp.setter
    def tdamp(self, value):
        fixed('tdamp')

    @pdamp.setter
    def pdamp(self, value):
        fixed('pdamp')

    @property
    def seed(self) -> int:
        """The key of the thermostat's noise."""
        return self._seed

    @property
    def barostat_position(self) -> float:
        """``lambda``: the cell is ``lambda`` times the construction cell."""
        return self.system.lam_value()

    @property
    def barostat_momentum(self) -> float:
        """``p_lambda``, eV ASE time."""
        return float(self.system.p_lam.floats[0])

    @property
    def barostat_mass(self) -> float:
        """``W``, eV (ASE time)**2 (module docstring)."""
        return self.system.W

    @property
    def reference_cell(self) -> np.ndarray:
        """``cell0``, Å: the cell at ``lambda = 1`` (a copy)."""
        return self.system.cell0.copy()

    @property
    def heat(self) -> float:
        """Kinetic energy the thermostat (and the piston's friction)
        added since the anchor, eV."""
        piston = self.friction_step.piston
        return self.friction_step.heat + (0.0 if piston is None
                                          else piston.heat)

    def get_conserved_energy(self) -> float:
        """``E_atoms + P V + p_lambda**2 / 2W - 2 kT ln lambda`` less the
        heat the thermostat added since the anchor, eV: conserved but for
        the time-step error."""
        self._sync()
        return self._balance()[0]

    def todict(self):
        """ASE's description plus the ensemble's settings and the quanta."""
        return {**super().todict(), 'temperature_K': self.temperature_K,
                'pressure_au': self.pressure_au, 'tdamp': self.tdamp,
                'pdamp': self.pdamp, 'seed': self._seed,
                **self.system.grid.todict(),
                'force_purity': self.force_purity.mode}


def _load_piston(piston, saved):
    """Take the piston's buffers from a buffer file's arrays."""
    for key in saved:
        if key.startswith('piston_') and key.endswith('_state'):
            n = int(key.split('_')[1])
            buffer = None if piston is None else piston.buffers.get(n)
            if buffer is None:
                raise ValueError(
                    'The buffer file was written with another pdamp or '
                    'time step: construct with those of the run that '
                    'wrote it.')
            buffer.load(saved[key], saved[f'piston_{n}_top'],
                        saved[f'piston_{n}_words'])


def _warn_new_run(why):
    warnings.warn(
        f'The restart record of these atoms cannot be resumed ({why}); '
        'ReversibleIsotropicNPT starts a new run here, with this cell as '
        'the reference cell and time from 0.', AnchorMovedWarning,
        stacklevel=5)


def _checked_pressure(value):
    try:
        value = float(value)
    except (TypeError, ValueError):
        raise TypeError('pressure_au must be a number (eV/Å**3, e.g. '
                        f'1.0 * ase.units.GPa), got {value!r}') from None
    if not math.isfinite(value):
        raise ValueError(f'pressure_au must be finite (eV/Å**3), got '
                         f'{value!r}')
    return value


def _refuse_cell(atoms):
    from ase import Atoms
    if not isinstance(atoms, Atoms):
        return  # admit() refuses it with its own message
    if not atoms.pbc.all():
        raise ValueError(
            'ReversibleIsotropicNPT needs atoms periodic in all three '
            f'directions (pbc is {atoms.pbc.tolist()}): the pressure is '
            'that of a periodic cell. Set atoms.pbc = True with a cell '
            'around the atoms, or use ReversibleLangevin for a cluster.')
    if not cell_volume(atoms.cell.array) > 0:
        raise ValueError('ReversibleIsotropicNPT needs a cell of positive '
                         f'volume, got {atoms.cell.array.tolist()}.')


def _refuse_constraints(atoms):
    if len(getattr(atoms, 'constraints', ())):
        raise UnsupportedConstraintError(
            'ReversibleIsotropicNPT supports no constraints yet (got '
            f'{", ".join(type(c).__name__ for c in atoms.constraints)}): '
            'a constraint would have to move with the cell. Remove them '
            '(del atoms.constraints).')


def _refuse_stressless(atoms):
    try:
        stress = atoms.get_stress(voigt=True, apply_constraint=False)
    except (PropertyNotImplementedError, NotImplementedError,
            AttributeError) as error:
        raise ValueError(
            f'ReversibleIsotropicNPT needs the stress, and '
            f'{type(atoms.calc).__name__} does not give it ({error!r}): '
            'the piston is pushed by it. Use a calculator that computes '
            'the stress (ASE EMT or LennardJones, asap3, '
            'ase_reversible.LennardJones).') from None
    if np.shape(stress) != (6,) or not np.isfinite(stress).all():
        raise ValueError(f'The stress of {type(atoms.calc).__name__} is not '
                         f'six finite numbers: {stress!r}.')


def _resumed_noise(section, timestep):
    try:
        if section is not None and float(section['timestep']) == abs(
                timestep):
            return {'seed': int(section['seed']),
                    'step': int(section['step'])}
    except (KeyError, TypeError, ValueError):
        pass
    return None
