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
counter-based generator.  Its friction is ``1 / tdamp``.  One step is the
palindrome ``B/2 P/2 T/2 O T/2 P/2 B/2`` (B the ``U`` part, P the piston,
T the kinetic part), with one force and stress call, at the step's end as
in velocity Verlet.

The barostat's mass.  ASE's ``IsotropicMTKNPT`` moves ``eps = ln(V/V0) / 3
= ln lambda`` with the mass ``W_eps = (3N + 3) kT pdamp**2``, so that the
volume oscillates with a period of the order of ``pdamp``.  The kinetic
energy ``W_eps (d eps/dt)**2 / 2 = W_eps (d lambda/dt)**2 / (2 lambda**2)``
equals ``W (d lambda/dt)**2 / 2`` at the construction volume for ``W =
W_eps``: that is the ``W`` used (``lambda`` stays near 1, the volume
moving by a few per cent).

Only fully periodic cells are supported: for a cluster ``-dU/dlambda``
would be the virial ``sum x.F / lambda``, and ``V`` has no meaning.
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
from ..core.engine import Engine, InvariantCheck
from ..core.plans import SubStep
from ..core.record import read_record
from ..core.variables import ExactVariable
from ..errors import (AnchorMovedWarning, UnstableIntegrationError,
                      UnsupportedConstraintError)
from .base import ReversibleDynamics
from .checks import check_energy_watch, check_timestep, fixed
from .hamiltonian import Drift, Hamiltonian, Kick, largest_kick
from .langevin import (Friction, _checked_friction, _checked_positive,
                       _checked_seed)
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

#: Default steps between checks of the energy balance.
ENERGY_CHECK_INTERVAL = 100

#: Quantum of ``lambda`` (starts at 1): 2**-44 moves a position of 2**43
#: position quanta (the default grid's range over 1024) by half a quantum,
#: and leaves 2**9 of range.
LAMBDA_QUANTUM = 2.0**-44
#: Bits of ``sqrt(W kT)`` (the spread of ``p_lambda``) below its quantum:
#: 32 leave ``p_lambda`` a range of 2**21 spreads, for the far from
#: equilibrium start of a run at a pressure far from the system's own.
P_LAMBDA_BITS = 32
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
        np.multiply(self.cell0, self.lam_value(),
                    out=self.atoms.cell.array)

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


class ScaledKick(Kick):
    """``pi += round_odd(c h lambda F(lambda rho) / q_p)``; the forces and
    the stress come from one calculator call per value of ``rho`` and
    ``lambda``."""

    def forget(self):
        super().forget()
        self._stress = self._saved_stress = self._applied = None

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
    recomputed from a clean neighbour list.
    """

    def __init__(self, system):
        self.system = system

    def prepare(self, ch):
        return ch / self.system.p_lam.quantum

    def force(self, trace):
        s = self.system
        lam = s.lam_value()
        return (-(lam * lam) * s.V0 * (trace + 3.0 * s.pressure)
                + 2.0 * s.kT / lam)

    def apply(self, scale):
        s = self.system
        kick = s.kick
        y = scale * self.force(kick.stress_trace())
        purity = s.purity
        if purity.mode == 'guarded' and not kick.stress_is_clean():
            bound = abs(scale) * self.noise_bound()
            if abs(y - round(y)) > 0.5 - bound:
                y = scale * self.force(kick.clean_stress_trace())
        _add_rounded(s.p_lam, y)

    def noise_bound(self):
        """Bound on the history noise of ``G`` (eV): ``lambda**2 V0
        tr(sigma)`` is ``V tr(sigma) / lambda``, a sum over atoms of a
        distance times a force, each below the cell's longest row sum
        times the forces' noise bound."""
        s = self.system
        atoms = s.atoms
        f_nc = s.kick.forces()
        reach = float(np.abs(atoms.cell.array).sum(axis=1).max()) \
            + float(np.abs(atoms.positions).max(initial=0.0))
        return 9.0 * len(atoms) * reach * s.purity.noise_bound(atoms, f_nc) \
            / s.lam_value()



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


class ScaledFriction(Friction):
    """Langevin's exact O step on ``pi``, whose mass is ``m lambda**2``:
    the noise's spread is ``lambda`` times that for the mass ``m``, and
    the heat it adds is measured with ``1 / (m lambda**2)``."""

    def apply(self, prepared):
        if prepared is None:
            return
        lam = self.system.lam_value()
        parts = list(prepared)
        parts[3] = prepared[3] * lam
        parts[6] = prepared[6] / (lam * lam)
        super().apply(tuple(parts))

    def adjoint(self, cotangents, ch):
        raise NotImplementedError(_NO_GRADIENTS)


_NO_GRADIENTS = (
    'backpropagate is not available for ReversibleIsotropicNPT yet: the '
    'adjoint of the barostat\'s sub-steps (which needs the derivative of '
    'the stress with respect to positions) is not written. Differentiate '
    'through a fixed-cell run (ReversibleLangevin, ReversibleNose, '
    'ReversibleVerlet) instead.')


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
                  P_LAMBDA: math.ldexp(_power_of_two_below(spread),
                                       -P_LAMBDA_BITS)}
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
        friction_step = ScaledFriction(
            system, lambda: (friction, system.temperature_K, True, self._seed),
            self._step_of)
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
        for n, b in self.friction_step.active_buffers().items():
            depth = int(b.top_k.max(initial=0))
            arrays[f'buffer_{n}_state'] = b.state_k
            arrays[f'buffer_{n}_top'] = b.top_k
            arrays[f'buffer_{n}_words'] = b.words_jk[:depth]
        with open(path, 'wb') as f:
            np.savez(f, **arrays)

    # -- what the steps read ------------------------------------------------

    def _step_of(self):
        engine = self.engine
        return engine.step_index if engine.direction > 0 \
            else engine.step_index - 1

    def _balance(self):
        energy, proposed = self.system.energy()
        return (energy + self.system.barostat_energy()
                - self.friction_step.heat, proposed)

    def _balance_trigger(self):
        system = self.system
        return (system.kinetic_energy() + system.barostat_energy()
                - self.friction_step.heat)

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
        atoms, system = self.atoms, self.system
        if np.array_equal(atoms.cell.array, system.shown_cell()):
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

    def backpropagate(self, steps, *args, **kwargs):
        """Not available yet for constant pressure (raises
        NotImplementedError, changing nothing)."""
        raise NotImplementedError(_NO_GRADIENTS)

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
        """Kinetic energy the thermostat added since the anchor, eV."""
        return self.friction_step.heat

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
