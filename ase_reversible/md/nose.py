"""ReversibleNose: deterministic constant-temperature dynamics that runs back
exactly, with no memory that grows with the run.

Nosé's extended system (S. Nosé, "A unified formulation of the constant
temperature molecular dynamics methods", J. Chem. Phys. 81, 511 (1984))
adds a coordinate ``s > 0`` and its momentum ``pi`` to the atoms.  In
Nosé's virtual time, with virtual momenta ``p' = s p``, the extended
energy ``H = sum p'**2 / (2 m s**2) + U(x) + pi**2 / (2 Q) + g kT ln s``
is conserved.  It splits into three parts whose flows are shears -- each
adds to some variables a function of variables it leaves alone:

* ``A = sum p'**2 / (2 m s**2) + g kT ln s`` (a function of ``p'`` and
  ``s``): ``x += h p' / (m s**2)`` and ``pi += h (sum p'**2 / (m s**3) -
  g kT / s)``;
* ``B = U(x)``: ``p' += h F(x)``, the kick of :mod:`.hamiltonian`;
* ``C = pi**2 / (2 Q)``: ``s += h pi / Q``.

Each update is rounded odd to its quantum, so each is undone exactly with
``-h``, and the step ``B/2 C/2 A C/2 B/2`` is a palindrome: one force call,
with the forces at the step's end as in velocity Verlet, one drift of the
positions, and no buffer (``scheme='velocity'``).  Its thermostat kicks
read the momenta half kicked, which it holds at ``T``; the frames show the
momenta at the step's end, cooler by ``O(dt**2)``.  ``A/2 C/2 B C/2 A/2``
(``scheme='position'``; ``B`` and ``C`` commute) kicks ``pi`` with the
momenta the frames show; docs/thermostats.md has the measured comparison.

The chain (``tchain = M > 1``; cf. B. Leimkuhler and C. Sweet, SIAM J.
Appl. Dyn. Syst. 4, 187 (2005), for recursive thermostats in one virtual
time) thermostats the thermostats::

    H = sum p'**2 / (2 m s_1**2) + U(x) + g kT ln s_1
        + sum_(j<M) pi_j**2 / (2 Q_j s_(j+1)**2) + pi_M**2 / (2 Q_M)
        + sum_(j>1) phi(s_j),    phi(s) = kT (a (s - 1) - (a - 1) ln s).

With ``p = p' / s_1`` and ``u_j = pi_j / s_(j+1)`` (``u_M = pi_M``; the
Jacobian is ``s_1**N_f s_2 ... s_M``), ``H = H_0 + sum u_j**2 / (2 Q_j) +
g kT ln s_1 + sum phi(s_j)``, and integrating the microcanonical density
over ``s_1`` leaves ``exp(-H_0 / kT) prod_j exp(-u_j**2 / (2 Q_j kT))
prod_(j>1) s_j exp(-phi(s_j) / kT)`` for ``g = N_f + 1``: canonical in the
atoms' ``x`` and ``p``, whatever ``phi`` is, provided each ``s_j``'s weight
is normalisable.  A bare ``g_j kT ln s_j`` (the single thermostat's term
repeated) gives ``s**(1 - g_j)``, normalisable for no ``g_j``; this
``phi`` gives ``s**a exp(-a (s - 1))``, largest at ``s = 1`` and vanishing
at 0, with ``a`` = :data:`CHAIN_STIFFNESS`.  The force on ``pi_j``, ``j >
1``, is ``(u_(j-1)**2 / Q_(j-1) - kT) / s_j - a kT (s_j - 1) / s_j``: the
thermostat ``j`` heats or cools ``j - 1`` towards ``kT`` as a Nosé-Hoover
chain does, and is pulled back towards ``s_j = 1``.  Each term of ``C =
sum_j pi_j**2 / (2 Q_j s_(j+1)**2) + phi(s_(j+1))`` (link ``j``) is a
function of ``pi_j`` and ``s_(j+1)``, which it does not move: its flow is
the shear ``s_j += h pi_j / (Q_j s_(j+1)**2)``, ``pi_(j+1) += h (pi_j**2 /
(Q_j s_(j+1)**3) - phi'(s_(j+1)))``.  ``C/2`` is the links in a row, each
a half step, mirrored in the palindrome.  The masses are ASE's: ``Q_1 = g
kT tdamp**2``, ``Q_j = kT tdamp**2``.  ``tchain=1`` is the single
thermostat, bit for bit.

Which ensemble, and the clock.  Steps are equal in virtual time.
Integrating the microcanonical density of ``H`` over ``s`` leaves, for
the real variables ``x`` and ``p = p' / s``, the weight ``exp(-(N_f + 1)
H_0 / (g kT))`` (``H_0`` the atoms' energy, ``N_f`` the momenta's degrees
of freedom): averages over virtual time -- over the frames of a run -- are
canonical for ``g = N_f + 1`` (Nosé 1984, section 2), which is the ``g``
used.  Real time runs at ``dt = dtau / s``; it is a further exact variable
updated during ``A`` (where ``s`` is fixed), so
:meth:`ReversibleNose.get_time` is real time and runs back exactly too.

``N_f`` counts the free momentum coordinates (the trace of the constraint
projection), less 3 when there are no constraints: the forces then sum to
zero and the total virtual momentum is conserved.  That count assumes the
total momentum is zero (``ase.md.velocitydistribution.Stationary``).  With
FixCom it is exactly zero (:class:`~.constraints.FixedCentre`: the virtual
momentum counts sum to zero at every step) and ``N_f`` is the free
coordinates less one per Cartesian component that has any.
"""

from __future__ import annotations

import math
import warnings

import numpy as np
from ase import units

from ..core.arguments import checked_positive
from ..core.codec import power_of_two_below, round_odd
from ..core.compositions import composition_for
from ..core.engine import Engine, InvariantCheck
from ..core.plans import SubStep
from ..core.portable import dot
from ..core.record import read_record
from ..core.variables import ExactVariable
from ..errors import (AnchorMovedWarning, QuantumRangeError,
                      UnstableIntegrationError)
from .admission import projected_momenta
from .base import ReversibleDynamics
from .checks import check_energy_watch, check_timestep, fixed
from .constraints import no_projection
from .hamiltonian import Drift, Hamiltonian, largest_kick
from .watch import SystemWatch

S, PI, CLOCK = 'thermostat_position', 'thermostat_momentum', 'time'
DRIFT, KICK, S_DRIFT, PI_KICK, TICK = ('drift', 'kick', 's-drift',
                                       'pi-kick', 'tick')

#: Default length of the chain (``tchain``): the single thermostat.  A
#: chain samples a crystal better, but its coordinates wander near zero,
#: where it stops with an error unless its thermostat is slow
#: (docs/thermostats.md, "A chain of thermostats"); ASE's call with
#: ``tchain=3`` is accepted unchanged.
TCHAIN = 1

#: Confinement of the chain's coordinates ``s_j``, ``j >= 2``: each has the
#: potential ``kT (a (s - 1) - (a - 1) ln s)`` (module docstring), which
#: gives it the weight ``s**a exp(-a (s - 1))``, largest at ``s = 1``.
CHAIN_STIFFNESS = 4.0


def link(j):
    """The name of the sub-step that moves ``s_j`` (``j`` from 1)."""
    return S_DRIFT if j == 1 else f'{S_DRIFT}-{j}'


def chain_names(j):
    """The names of ``s_j`` and ``pi_j`` (``j`` from 1): the first link
    keeps the names of the single thermostat."""
    return (S, PI) if j == 1 else (f'{S}_{j}', f'{PI}_{j}')


def step_scheme(kind='velocity', tchain=1):
    """The sub-steps of a step, ``(name, fraction of the time step)``.

    ``'velocity'``: ``B/2 C/2 A C/2 B/2`` (module docstring): the forces at
    the step's end, and the thermostat's kicks reading the momenta half
    kicked.  ``'position'``: ``A/2 C/2 B C/2 A/2``: the force call in the
    middle of the step (``B`` and ``C`` commute), and the thermostat's kicks
    reading the momenta at the step's ends, those the frames show; the
    step ends with the drift of the positions, so the kick is one drift
    back, as the restart record's digest of the forces expects.  The
    three parts of ``A`` depend on ``p'`` and ``s_1`` only, which none of
    them changes, so they commute.  ``C/2`` is the chain's links, the
    first next to ``A``, each a half step.  Both are palindromes, hence
    exactly undone with ``-h``.
    """
    inner = tuple((link(j), 0.5) for j in range(1, tchain + 1))
    a_half = ((TICK, 0.5), (PI_KICK, 0.5))
    if kind == 'velocity':
        half = ((KICK, 0.5),) + inner[::-1] + a_half[::-1]
        middle = ((DRIFT, 1.0),)
    elif kind == 'position':
        half, middle = ((DRIFT, 0.5),) + a_half + inner, ((KICK, 1.0),)
    else:
        raise ValueError(f"scheme must be 'velocity' or 'position', got "
                         f'{kind!r}')
    return half + middle + half[::-1]


SCHEMES = ('velocity', 'position')
#: The default scheme; a record without a ``'scheme'`` was written by it.
SCHEME_DEFAULT = 'velocity'
SCHEME = step_scheme(SCHEME_DEFAULT)

#: Centre-of-mass kinetic energy (in kT) above which unconstrained atoms
#: are warned about: a thermal centre of mass has 1.5 kT, one at rest
#: (``Stationary``) a few momentum quanta.
CENTRE_OF_MASS_TOLERANCE = 0.01

#: Default steps between checks of the extended energy.
ENERGY_CHECK_INTERVAL = 100

#: Quantum of ``s`` (dimensionless, starts at 1): 2**-40 leaves 2**12 of
#: range above 1 and resolves an increment of ``h pi / Q`` to 2**-40.
S_QUANTUM = 2.0**-40
#: Bits of ``sqrt(Q kT)`` (the spread of ``pi``) below its quantum.
PI_BITS = 40
#: Bits of ``|dt|`` below the clock's quantum: the clock rounds each half
#: step to 2**-24 of the time step and runs for 2**28 steps of ``|dt|``
#: before its counts reach 2**53.
CLOCK_BITS = 24
#: Virtual momentum counts below this are recovered exactly from a
#: frame's momenta ``p' / s`` and ``s`` (two roundings of 2**-53 each);
#: above, the record stores them.
RECOVERABLE = 2.0**50



def thermostat_mass(g, kT, tdamp):
    """Nosé's ``Q = g kT tdamp**2``, eV (ASE time)**2 (``kT`` in eV,
    ``tdamp`` in ASE time units): the thermostat's period is of the order
    of ``tdamp``."""
    return g * kT * (tdamp * tdamp)


def chain_masses(g, kT, tdamp, tchain):
    """``[Q_1, ..., Q_M]``, eV (ASE time)**2: ``Q_1 = g kT tdamp**2`` and
    ``kT tdamp**2`` for the others, as ASE's ``NoseHooverChainNVT`` sets
    its chain's masses."""
    return [thermostat_mass(g if j == 0 else 1, kT, tdamp)
            for j in range(tchain)]


def confinement(kT, s, a=None):
    """``phi(s) = kT (a (s - 1) - (a - 1) ln s)``, eV: the potential of a
    chain coordinate after the first."""
    a = CHAIN_STIFFNESS if a is None else a
    return kT * (a * (s - 1.0) - (a - 1.0) * math.log(s))


def confinement_force(kT, s, a=None):
    """``phi'(s) = kT (a - (a - 1) / s)``, eV."""
    a = CHAIN_STIFFNESS if a is None else a
    return kT * (a - (a - 1.0) / s)


def confinement_curvature(kT, s, a=None):
    """``phi''(s) = kT (a - 1) / s**2``, eV."""
    a = CHAIN_STIFFNESS if a is None else a
    return kT * (a - 1.0) / (s * s)


def degrees_of_freedom(n_atoms, project):
    """``N_f``: the free momentum coordinates, less 3 without constraints
    (the total momentum is then conserved), less one per Cartesian
    component with a free coordinate under FixCom (its total momentum is
    held at zero)."""
    if project is no_projection:
        return 3 * n_atoms - 3
    trace = 0.0
    for c in range(3):
        unit_nc = np.zeros((n_atoms, 3))
        unit_nc[:, c] = 1.0
        project(unit_nc)
        trace += float(unit_nc[:, c].sum())
    centre = getattr(project, 'centre', None)
    held = 0 if centre is None else centre.components
    return int(round(trace)) - held


class NoseHamiltonian(Hamiltonian):
    """The atoms with Nosé's thermostat: ``'momentum'`` holds the virtual
    momenta ``p' = s p``, the atoms show ``p = p' / s``; ``s``, ``pi`` and
    the real time are exact variables of shape ``[1]``.

    Parameters as for :class:`~.hamiltonian.Hamiltonian`; the thermostat is
    set with :meth:`set_thermostat`.
    """

    def __init__(self, atoms, grid, counts, masses_n, project, purity):
        self.kT = self.tdamp = None
        self.tchain = 1
        super().__init__(atoms, grid, counts, masses_n, project, purity)
        self.drift = ScaledDrift(self)
        self._shown_nc = np.empty(self.p.ints.shape)
        self._shown_key = None

    def set_thermostat(self, counts, quanta, temperature_K, tdamp,
                       tchain=1):
        """Take ``s_j``, ``pi_j`` (``j`` = 1 to ``tchain``) and the clock
        from ``counts`` (int64 ``[1]`` by name) in ``quanta``, at
        ``temperature_K`` (K) and ``tdamp`` (ASE time units)."""
        self.tchain = tchain
        self.chain_s, self.chain_pi = [], []
        for j in range(1, tchain + 1):
            for name, kept in zip(chain_names(j),
                                  (self.chain_s, self.chain_pi)):
                kept.append(ExactVariable(name, counts[name], quanta[name]))
                self.variables[name] = kept[-1]
        self.s, self.pi = self.chain_s[0], self.chain_pi[0]
        self.clock = ExactVariable(CLOCK, counts[CLOCK], quanta[CLOCK])
        self.variables[CLOCK] = self.clock
        self.tdamp = tdamp
        self.set_temperature(temperature_K)

    def set_temperature(self, temperature_K):
        """Thermostat at ``temperature_K`` (K); the masses ``Q_j`` follow."""
        self.temperature_K = temperature_K
        self.kT = units.kB * temperature_K
        self._set_mass()

    def set_dynamics(self, masses_n, project, purity):
        super().set_dynamics(masses_n, project, purity)
        self.degrees_of_freedom = degrees_of_freedom(len(masses_n), project)
        if self.degrees_of_freedom < 1:
            raise ValueError('ReversibleNose needs at least one free degree '
                             'of freedom; every momentum is constrained.')
        self.g = self.degrees_of_freedom + 1
        if self.kT is not None:
            self._set_mass()

    def _set_mass(self):
        self.masses_Q = chain_masses(self.g, self.kT, self.tdamp,
                                     self.tchain)
        self.Q = self.masses_Q[0]

    # -- what the atoms show ----------------------------------------------

    def s_value(self) -> float:
        """``s``, its exact float image."""
        return float(self.s.floats[0])

    def shown_momenta(self):
        key = (self.p.label, self.s.label)
        if self._shown_key != key:
            np.divide(self.p.floats, self.s_value(), out=self._shown_nc)
            self._shown_key = key
        return self._shown_nc

    def show_momenta(self):
        momenta = self.atoms.arrays.get('momenta')
        if momenta is None:
            self.atoms.set_momenta(self.shown_momenta(),
                                   apply_constraint=False)
        else:
            np.copyto(momenta, self.shown_momenta())

    def virtual_counts(self, momenta_nc, s_value):
        """The virtual momentum counts ``rint(p s / q_p)`` of real momenta
        ``momenta_nc`` ``[n_atoms, 3]`` (projected) at ``s``."""
        y_nc = momenta_nc * (s_value / self.p.quantum)
        if self.centre is not None:
            # FixCom: zero total, as the drift and kick keep it.
            self.centre.balance(round_odd(y_nc, out=y_nc))
        return round_odd(y_nc).astype(np.int64)

    # -- energies ---------------------------------------------------------

    def thermostat_energy(self) -> float:
        """The chain's energy, eV: ``sum_j pi_j**2 / (2 Q_j s_(j+1)**2)``
        (no ``s`` after the last) ``+ g kT ln s_1 + sum_(j>1) phi(s_j)``."""
        # libm's log may differ between CPUs in the last bit: harmless,
        # only the energy check reads this, never a step.
        s_j = [float(v.floats[0]) for v in self.chain_s] + [1.0]
        energy = 0.0
        for j, (pi, Q) in enumerate(zip(self.pi_values(), self.masses_Q)):
            energy += 0.5 * pi * pi / (Q * s_j[j + 1] * s_j[j + 1])
            if j:
                energy += confinement(self.kT, s_j[j])
        return energy + self.g * self.kT * math.log(s_j[0])

    def pi_values(self):
        """``pi_j``, their exact float images."""
        return [float(v.floats[0]) for v in self.chain_pi]

    def kinetic_energy(self):
        """The atoms' real kinetic energy ``sum p'**2 / (2 m s**2)``, eV."""
        s = self.s_value()
        return 0.5 * self.momentum_square() / (s * s)

    def extended_energy(self):
        """``(H, proposed tolerance)``, eV: the conserved extended energy
        and the tolerance the energy check proposes."""
        energy, proposed = self.energy()
        return energy + self.thermostat_energy(), proposed


class ScaledDrift(Drift):
    """``x += round_odd(c h P p' / (m s**2) / q_x)``."""

    def apply(self, prepared):
        s = self.system
        self._drift(prepared, (s.p.label, s.s.label, prepared[0]),
                    1.0 / (s.s_value() * s.s_value()))

    def adjoint(self, cotangents, ch):
        """``a_p' += c h P a_x / (m s**2)``; ``a_s -= 2 c h a_x . P p' /
        (m s**3)``."""
        cotangents.flush()
        sys, s = self.system, self.system.s_value()
        w_nc = np.divide(cotangents['position'], sys.m_n1)
        sys.project(w_nc)
        cotangents[S] -= 2.0 * ch / (s * s * s) * dot(w_nc, sys.p.floats)
        cotangents['momentum'] += (ch / (s * s)) * w_nc



class ThermostatKick(SubStep):
    """``pi += round_odd(c h (sum p'**2 / (m s**3) - g kT / s) / q_pi)``.

    The force on ``pi`` is computed once per value of ``p'`` and ``s``: the
    two half kicks of a step share it.
    """

    def __init__(self, system):
        self.system = system
        self._key = self._force = None

    def prepare(self, ch):
        return ch / self.system.pi.quantum

    def force(self):
        """``sum p'**2 / (m s**3) - g kT / s``, eV / (ASE time unit)
        per ASE time unit of virtual time."""
        sys = self.system
        key = (sys.p.label, sys.s.label)
        if self._key != key:
            s = sys.s_value()
            two_k = sys.momentum_square()  # sum p'^2 / m
            self._force = two_k / (s * s * s) - sys.g * sys.kT / s
            self._key = key
        return self._force

    def apply(self, scale):
        self.system.pi.add_rounded(scale * self.force())

    def adjoint(self, cotangents, ch):
        """``a_p' += c h a_pi 2 p' / (m s**3)``; ``a_s += c h a_pi (g kT /
        s**2 - 3 sum p'**2 / (m s**4))``."""
        cotangents.flush()
        sys = self.system
        a_pi = float(cotangents[PI][0])
        if a_pi == 0.0:
            return
        s = sys.s_value()
        two_k = sys.momentum_square()
        s2 = s * s
        cotangents[S] += ch * a_pi * (sys.g * sys.kT / s2
                                      - 3.0 * two_k / (s2 * s2))
        cotangents['momentum'] += (2.0 * ch * a_pi / (s2 * s)) * (
            sys.p.floats / sys.m_n1)


_CHAIN_ADVICE = (
    'the chain is unstable at this tdamp and time step (a chain coordinate '
    's_j came near zero, where its link stiffens). Use a larger tdamp (40 '
    'time steps or more; 100 is usual), a smaller time step, or tchain=1. '
    'The step was not taken; the state is valid and reversible.')


class ThermostatDrift(SubStep):
    """The flow of the chain's link ``j`` (from 1), ``pi_j**2 / (2 Q_j
    s_(j+1)**2) + phi(s_(j+1))``, a function of ``pi_j`` and ``s_(j+1)``:
    ``s_j += round_odd(c h pi_j / (Q_j s_(j+1)**2) / q)`` and ``pi_(j+1) +=
    round_odd(c h (pi_j**2 / (Q_j s_(j+1)**3) - phi'(s_(j+1))) / q)``.
    The last link is ``pi_M**2 / (2 Q_M)``: ``s_M += round_odd(c h pi_M /
    Q_M / q)``.  Every ``s_j`` must stay positive.
    """

    def __init__(self, system, j=1):
        self.system, self.j = system, j

    def prepare(self, ch):
        sys, j = self.system, self.j
        factor = ch / (sys.masses_Q[j - 1] * sys.chain_s[j - 1].quantum)
        if j == sys.tchain:
            return factor
        return factor, ch / sys.chain_pi[j].quantum

    def apply(self, prepared):
        sys, j = self.system, self.j
        pi = float(sys.chain_pi[j - 1].floats[0])
        s_j = sys.chain_s[j - 1]
        if sys.tchain == 1:
            s_j.add_rounded(prepared * pi)
        else:
            try:
                self._apply_link(prepared, pi)
            except QuantumRangeError as error:
                raise UnstableIntegrationError(
                    f'The thermostat chain left the range of its fixed '
                    f'point at link {j} ({error}): {_CHAIN_ADVICE}'
                ) from error
        if not s_j.floats[0] > 0.0:
            if sys.tchain == 1:
                raise UnstableIntegrationError(
                    'The Nosé thermostat coordinate s reached zero: the '
                    'thermostat is unstable. Use a larger tdamp or a '
                    'smaller time step. The step was not taken; the state '
                    'is valid and reversible.')
            raise UnstableIntegrationError(
                f'The thermostat chain\'s coordinate s_{j} reached zero: '
                f'{_CHAIN_ADVICE}')

    def _apply_link(self, prepared, pi):
        sys, j = self.system, self.j
        s_j = sys.chain_s[j - 1]
        if j == sys.tchain:
            s_j.add_rounded(prepared * pi)
            return
        factor, scale = prepared
        s = float(sys.chain_s[j].floats[0])
        inverse_square = 1.0 / (s * s)
        s_j.add_rounded(factor * pi * inverse_square)
        sys.chain_pi[j].add_rounded(scale * (
            pi * pi * inverse_square / (sys.masses_Q[j - 1] * s)
            - confinement_force(sys.kT, s)))

    def adjoint(self, cotangents, ch):
        """``a_pi_j += c h (a_s_j / (Q s**2) + a_pi_(j+1) 2 pi_j / (Q
        s**3))``; ``a_s_(j+1) -= c h (a_s_j 2 pi_j / (Q s**3) + a_pi_(j+1)
        (3 pi_j**2 / (Q s**4) + phi''(s)))``, ``s = s_(j+1)``, ``Q = Q_j``;
        the last link: ``a_pi_M += c h a_s_M / Q_M``."""
        sys, j = self.system, self.j
        s_name, pi_name = chain_names(j)
        Q = sys.masses_Q[j - 1]
        if j == sys.tchain:
            cotangents[pi_name] += ch / Q * cotangents[s_name]
            return
        next_s, next_pi = chain_names(j + 1)
        a_s = float(cotangents[s_name][0])
        a_next = float(cotangents[next_pi][0])
        pi = float(sys.chain_pi[j - 1].floats[0])
        s = float(sys.chain_s[j].floats[0])
        s2 = s * s
        cotangents[pi_name] += ch * (a_s / (Q * s2)
                                     + a_next * 2.0 * pi / (Q * s2 * s))
        cotangents[next_s] -= ch * (
            a_s * 2.0 * pi / (Q * s2 * s)
            + a_next * (3.0 * pi * pi / (Q * s2 * s2)
                        + confinement_curvature(sys.kT, s)))


class Tick(SubStep):
    """The real-time clock: ``t += round_odd(c h / s / q_t)``.  Nothing
    depends on it, so its adjoint is empty."""

    def __init__(self, system):
        self.system = system

    def prepare(self, ch):
        return ch / self.system.clock.quantum

    def apply(self, scale):
        self.system.clock.add_rounded(scale / self.system.s_value())

    def adjoint(self, cotangents, ch):
        pass


def _carry_keys(j):
    """The keys of ``dL/ds_j`` and ``dL/dpi_j`` in ``Gradients.thermostat``."""
    return ('s', 'pi') if j == 1 else (f's{j}', f'pi{j}')


def _check_tloop(tloop):
    if isinstance(tloop, bool) or tloop != 1:
        raise ValueError(
            f'tloop={tloop!r}: ReversibleNose accepts only tloop=1. ASE\'s '
            'NoseHooverChainNVT sub-cycles its chain tloop times a step; '
            'the exact chain is one Hamiltonian split into shears, with no '
            'sub-cycles. For a finer integration of the chain, use a '
            'smaller time step (or order=4).')


def _checked_tchain(tchain):
    if tchain is None:
        return None
    if (isinstance(tchain, bool) or not isinstance(tchain, (int, np.integer))
            or tchain < 1):
        raise ValueError(f'tchain must be a whole number of thermostats, '
                         f'1 or more (e.g. 3), got {tchain!r}')
    return int(tchain)


def _chain_of_record(atoms, tchain, scheme):
    """``(tchain, scheme)``: those given, else those of the frame's restart
    record, else the defaults.  A frame written with another chain or
    scheme is refused: resuming it with another dynamics would silently
    be a different run."""
    record = read_record(atoms.info, names=(), sections=('nose',))
    section = record.get('nose') if record else None
    if section is None:
        return (TCHAIN if tchain is None else tchain,
                SCHEME_DEFAULT if scheme is None else scheme)
    written = (section.get('tchain', 1), section.get('scheme',
                                                      SCHEME_DEFAULT))
    wanted = (written[0] if tchain is None else tchain,
              written[1] if scheme is None else scheme)
    if wanted != written:
        raise ValueError(
            f'These atoms carry the restart record of a ReversibleNose run '
            f'with tchain={written[0]}, scheme={written[1]!r}; asked for '
            f'tchain={wanted[0]}, scheme={wanted[1]!r}. Leave tchain and '
            'scheme out (or pass those of the record) to resume that run '
            'exactly, or remove the record (atoms.info.pop(\'reversible\')) '
            'to start a new run from these atoms.')
    return wanted


def _warn_if_moving(system):
    """Warn if unconstrained atoms move as a whole: the thermostat then
    cannot give the internal motion the canonical distribution."""
    if system.project is not no_projection:
        return
    momentum_c = system.p.floats.sum(axis=0)
    drift = 0.5 * dot(momentum_c, momentum_c) / float(system.m_n1.sum())
    if drift > CENTRE_OF_MASS_TOLERANCE * system.kT:
        warnings.warn(
            f'The atoms move as a whole (centre-of-mass kinetic energy '
            f'{drift / system.kT:.3g} kT). Without constraints ReversibleNose '
            'conserves the total (virtual) momentum and thermostats 3N - 3 '
            'degrees of freedom: the frames are canonical only at zero '
            'total momentum. Call ase.md.velocitydistribution.Stationary('
            'atoms) before constructing it.', UserWarning, stacklevel=3)


class ReversibleNose(ReversibleDynamics):
    """Nosé's constant-temperature dynamics in fixed point, run back
    exactly with no buffer: a deterministic NVT.

    The atoms and a chain of thermostats -- coordinates ``s_j`` and
    momenta ``pi_j``, ``s = s_1`` and ``pi = pi_1`` those of the first --
    evolve under a Hamiltonian in Nosé's virtual time (module docstring),
    split so that every update is an exact shear.  After ``run(n)``,
    :meth:`reverse` and ``run(n)``, positions, momenta, every ``s_j`` and
    ``pi_j`` and the clock are bitwise those right after the constructor,
    however long the run: nothing is stored.  The frames of a run sample
    the canonical distribution at ``temperature_K`` if the dynamics is
    ergodic, which a single thermostat is not for small or stiff systems
    (a handful of atoms, a cold harmonic crystal): a chain helps on a
    crystal (docs/thermostats.md, "A chain of thermostats"); for a handful
    of atoms use :class:`~ase_reversible.ReversibleLangevin`.

    The atoms show the real momenta ``p = p' / s``; the exact variable is
    the virtual momentum ``p'`` (``state`` and ``counts`` hold its
    counts).  Steps are equal in Nosé's virtual time;
    :meth:`ReversibleNose.get_time` is real time, which advances by ``dt /
    s`` per step.

    Parameters
    ----------
    atoms : ase.Atoms
        With a calculator attached; best with zero total momentum (module
        docstring), which FixCom holds exactly.
    timestep : float
        ASE time units (``5 * ase.units.fs``), in virtual time.
    temperature_K : float
        Target temperature, K.
    tdamp : float
        Characteristic time of the thermostat, ASE time units (``100 *
        timestep`` is a common choice, as for ASE's
        ``NoseHooverChainNVT``); the masses are ASE's, ``Q_1 = g kB T
        tdamp**2`` and ``kB T tdamp**2`` for the chain's others.
    tchain : int, optional
        Thermostats in the chain, 1 or more; default: that of the frame's
        restart record, else :data:`TCHAIN` (1: Nosé's single
        thermostat).  ASE's default, 3, samples a crystal better but
        needs ``tdamp`` of 40 steps or more, and may still stop with an
        error (docs/thermostats.md, "A chain of thermostats").
    tloop : int
        Accepted only as 1 (ASE's chain sub-cycles; this one has no
        sub-cycles: use a smaller time step).
    scheme : {'velocity', 'position'}, optional
        The arrangement of a step (:func:`step_scheme`); default: the
        record's, else ``'velocity'``, whose configurational averages
        hardly move with the time step (docs/thermostats.md, "Large time
        steps").
    trajectory, logfile, loginterval
        As for :class:`ase.md.verlet.VelocityVerlet`.
    order, composition
        As for :class:`~ase_reversible.ReversibleVerlet`: above 2, a step
        is a symmetric composition of the second-order step, still exactly
        reversible, one force call per stage.
    position_quantum, momentum_quantum, force_purity, force_noise
        As for :class:`~ase_reversible.ReversibleVerlet`.
    energy_check : int
        As for :class:`~ase_reversible.ReversibleVerlet`, for the extended
        energy :meth:`get_conserved_energy`.
    energy_tolerance : float, optional
        eV; default as for :class:`~ase_reversible.ReversibleVerlet`.
    **kwargs
        Passed to :class:`ase.md.md.MolecularDynamics`.

    A frame the run wrote resumes it bit for bit: the restart record
    (``atoms.info['reversible']``) holds every ``s_j``, ``pi_j``, their
    quanta, ``tchain`` and ``scheme``.

    Raises
    ------
    ValueError, TypeError
        A non-positive or non-finite temperature or tdamp, a ``tchain``
        that is not a whole number from 1, a ``tloop`` other than 1, an
        unknown ``scheme``, a ``tchain`` or ``scheme`` other than those of
        the frame's restart record, or the errors of
        :class:`~ase_reversible.ReversibleVerlet`.
    UnsupportedConstraintError
        As for :class:`~ase_reversible.ReversibleVerlet`.
    """

    record_sections = ('nose',)
    #: The labels of the state the last backpropagate ended at.
    _retrace_end = None

    def __init__(self, atoms, timestep, temperature_K, tdamp, *,
                 tchain=None, tloop=1, scheme=None,
                 trajectory=None, logfile=None, loginterval=1, order=2,
                 composition=None, position_quantum=None,
                 momentum_quantum=None,
                 force_purity='auto', force_noise=None,
                 energy_check=ENERGY_CHECK_INTERVAL, energy_tolerance=None,
                 **kwargs):
        _check_tloop(tloop)
        tchain = _checked_tchain(tchain)
        if scheme is not None and scheme not in SCHEMES:
            raise ValueError(f'scheme must be one of {SCHEMES}, got '
                             f'{scheme!r}')
        timestep = check_timestep(timestep)
        temperature_K = checked_positive(temperature_K, 'temperature_K',
                                         'K')
        tdamp = checked_positive(tdamp, 'tdamp', 'ASE time units, e.g. '
                                 '100 * ase.units.fs')
        energy_check, energy_tolerance = check_energy_watch(
            energy_check, energy_tolerance)
        composition = composition_for(order, composition)
        tchain, scheme = _chain_of_record(atoms, tchain, scheme)
        plan = step_scheme(scheme, tchain)
        system, record = self._hamiltonian(
            atoms, largest_kick(plan, composition, timestep, KICK),
            position_quantum, momentum_quantum,
            force_purity, force_noise, system_class=NoseHamiltonian)
        counts, quanta = self._thermostat_start(system, record, timestep,
                                                temperature_K, tdamp, tchain)
        system.set_thermostat(counts, quanta, temperature_K, tdamp, tchain)
        if record is not None and record.get('nose') is not None:
            self._resume_virtual_momenta(system, record['nose'])
        _warn_if_moving(system)
        substep = {KICK: system.kick, DRIFT: system.drift,
                   PI_KICK: ThermostatKick(system), TICK: Tick(system)}
        for j in range(1, tchain + 1):
            substep[link(j)] = ThermostatDrift(system, j)
        invariant = InvariantCheck(
            energy_check, energy_tolerance, system.extended_energy,
            self._explain_drift, trigger=self._trigger)
        engine = Engine(system.variables,
                        tuple((substep[k], c) for k, c in plan),
                        composition, timestep,
                        invariant=invariant)
        self._scheme = scheme
        self._attach(system, engine, (force_purity, force_noise),
                     record['time'] if record else 0.0)
        super().__init__(atoms, timestep, trajectory=trajectory,
                         logfile=logfile, loginterval=loginterval, **kwargs)
        self._start(SystemWatch(atoms))

    # -- construction -------------------------------------------------------

    @staticmethod
    def _thermostat_start(system, record, timestep, temperature_K, tdamp,
                          tchain=1):
        """Counts and quanta of ``s_j``, ``pi_j`` and the clock: from the
        record's ``'nose'`` section if it has one, else ``s_j = 1``,
        ``pi_j = 0``.  The clock counts from 0 (the record's time is
        added)."""
        kT = units.kB * temperature_K
        names = [name for j in range(1, tchain + 1)
                 for name in chain_names(j)]
        quanta = {CLOCK: math.ldexp(power_of_two_below(abs(timestep)),
                                    -CLOCK_BITS)}
        counts = {CLOCK: np.zeros(1, np.int64)}
        for j, Q in enumerate(chain_masses(system.g, kT, tdamp, tchain), 1):
            s_name, pi_name = chain_names(j)
            spread = math.sqrt(Q * kT)
            quanta[s_name] = S_QUANTUM
            quanta[pi_name] = math.ldexp(power_of_two_below(spread),
                                         -PI_BITS)
            counts[s_name] = np.array([round(1.0 / S_QUANTUM)], np.int64)
            counts[pi_name] = np.zeros(1, np.int64)
        section = record.get('nose') if record else None
        if section is not None:
            saved = read_record(system.atoms.info, names=names)
            try:
                pairs = [(int(section[S]), int(section[PI]))]
                pairs += [(int(s), int(pi))
                          for s, pi in section.get('chain', ())]
            except (KeyError, TypeError, ValueError):
                saved = None
            if (saved is not None and len(pairs) == tchain
                    and all(s > 0 for s, _ in pairs)):
                for j, pair in enumerate(pairs, 1):
                    for name, count in zip(chain_names(j), pair):
                        quanta[name] = saved[f'{name}_quantum']
                        counts[name][0] = count
            else:
                record['nose'] = None
        return counts, quanta

    def _resume_virtual_momenta(self, system, section):
        """Set ``p'`` from a frame: stored in the record, or recovered from
        the momenta shown, ``p' / s``, and checked to show them again
        bit for bit."""
        atoms = system.atoms
        momenta = atoms.arrays.get('momenta')
        stored = section.get('virtual_momentum')
        if stored is not None:
            counts = np.array(stored, dtype=np.int64).reshape(-1, 3)
        elif momenta is not None:
            counts = system.virtual_counts(momenta, system.s_value())
        else:
            counts = None
        if counts is not None and counts.shape == system.p.ints.shape:
            system.p.reset(counts)
            if momenta is not None and np.array_equal(
                    system.shown_momenta(), momenta):
                return
        # Not the frame the record was written with: begin afresh from
        # what the atoms show.
        system.p.reset(system.virtual_counts(
            projected_momenta(atoms, system.project),
            system.s_value()))
        warnings.warn(
            'The momenta of these atoms are not those their restart record '
            'was written with (edited since?); the thermostat goes on from '
            'the record, with the momenta as they are. This is a new run '
            'from here, not the old one resumed.',
            AnchorMovedWarning, stacklevel=4)

    def _grid_values(self, atoms):
        # The momenta shown are p' / s, off the grid: checked when p' is
        # recovered.
        return {'position': atoms.positions}

    def _encode(self, atoms, project):
        system = self.system
        counts = {'position': super()._encode(atoms, project)['position'],
                  'momentum': system.virtual_counts(
                      projected_momenta(atoms, project), system.s_value())}
        for name, variable in system.variables.items():
            if name not in counts:
                counts[name] = variable.ints
        return counts

    # -- what the run reads -----------------------------------------------

    def _trigger(self):
        system = self.system
        return system.kinetic_energy() + system.thermostat_energy()

    def _explain_drift(self, number, drift, tolerance):
        return (
            f'The extended energy (atoms plus Nosé thermostat) has changed '
            f'by {drift:.4g} eV since the anchor of reversal (tolerance '
            f'{tolerance:.4g} eV) after step {number}: the integration is '
            f'unstable. s is {self.thermostat_position:.3g}, so a step '
            f'is {abs(self.dt) / self.thermostat_position / units.fs:.3g} '
            'fs of real time. Use a smaller time step (now '
            f'{abs(self.dt) / units.fs:g} fs) or a larger tdamp (now '
            f'{self.tdamp / units.fs:g} fs), and start nearer the target '
            'temperature (s moves far from 1 when the thermostat has to '
            'heat or cool the atoms a lot). The step was not taken; the '
            'state is valid and reverse() leads back exactly. If the change '
            'is expected, raise energy_tolerance or pass energy_check=0.')

    def _ready(self):
        self.system.kick.forces()

    def get_time(self):
        """Real time in ASE time units (``sum dt / s`` over the steps),
        continued from a restart record; goes back when run backwards."""
        return self._time0 + float(self.system.clock.floats[0])

    def _record_sections(self):
        system = self.system
        section = {S: int(system.s.ints[0]), PI: int(system.pi.ints[0]),
                   'temperature_K': system.temperature_K,
                   'tdamp': system.tdamp, 'tchain': system.tchain,
                   'scheme': self._scheme}
        if system.tchain > 1:
            section['chain'] = [[int(s.ints[0]), int(pi.ints[0])]
                                for s, pi in zip(system.chain_s[1:],
                                                 system.chain_pi[1:])]
        if not system.p.bound < RECOVERABLE:
            section['virtual_momentum'] = system.p.ints.reshape(-1).tolist()
        return {'nose': section}

    # -- gradients ----------------------------------------------------------

    def _cotangents_of(self, ax_nc, ap_nc, carry):
        # The user's gradients are on (x, p, s, pi) with p = p' / s; the
        # exact variables are (x, p', s, pi): dL/dp' = dL/dp / s and
        # dL/ds at fixed p' = dL/ds at fixed p - dL/dp . p / s.
        here = self._retrace_key()
        if carry is None and here == self._retrace_end:
            raise ValueError(
                'The atoms are where the last backpropagate ended. To go on '
                'with a loss on several states, pass what it returned as '
                'carry= (the thermostat carries part of the gradient from '
                'one segment to the next); to start a new loss here, pass '
                'carry=False.')
        if carry and here != self._retrace_end:
            raise ValueError(
                'carry= goes on from where the last backpropagate ended, '
                'but the state has changed since: pass carry=False or none.')
        thermostat = carry.thermostat if carry else {}
        added = self._loss_cotangents(ax_nc, ap_nc)
        cotangents = {'position': ax_nc, 'momentum': added['momentum'],
                      CLOCK: np.zeros(1)}
        for j in range(1, self.system.tchain + 1):
            for name, key in zip(chain_names(j), _carry_keys(j)):
                cotangents[name] = np.array(
                    [float(thermostat.get(key, 0.0))])
        cotangents[S] += added[S]
        return cotangents

    def _loss_cotangents(self, ax_nc, ap_nc):
        if ap_nc is None:
            return {'position': ax_nc}
        system = self.system
        s = system.s_value()
        return {'position': ax_nc, 'momentum': ap_nc / s,
                S: np.array([-dot(ap_nc, system.shown_momenta()) / s])}

    def _gradients_of(self, cotangents):
        # Back to (x, p, s, pi): dL/dp = s dL/dp', dL/ds at fixed p =
        # dL/ds at fixed p' + dL/dp' . p.
        system = self.system
        s = system.s_value()
        ap_nc = cotangents['momentum'] * s
        a_s = float(cotangents[S][0]) + dot(cotangents['momentum'],
                                            system.shown_momenta())
        self._retrace_end = self._retrace_key()
        thermostat = {}
        for j in range(1, system.tchain + 1):
            for name, key in zip(chain_names(j), _carry_keys(j)):
                thermostat[key] = float(cotangents[name][0])
        thermostat['s'] = a_s
        return cotangents['position'].copy(), ap_nc, thermostat

    def _retrace_key(self):
        return tuple(v.label for v in self.system.variables.values())

    # -- the thermostat -----------------------------------------------------

    @property
    def temperature_K(self) -> float:
        """Target temperature, K (change it with :meth:`set_temperature`)."""
        return self.system.temperature_K

    @property
    def tdamp(self) -> float:
        """The thermostat's time, ASE time units (fixed at construction)."""
        return self.system.tdamp

    @tdamp.setter
    def tdamp(self, value):
        fixed('tdamp')

    @property
    def composition(self):
        """The :class:`~ase_reversible.core.compositions.Composition` in
        use (fixed at construction)."""
        return self.engine.composition

    @composition.setter
    def composition(self, value):
        fixed('composition (and order)')

    @property
    def thermostat_position(self) -> float:
        """Nosé's ``s`` (dimensionless): real time runs at ``1 / s`` of
        virtual time."""
        return self.system.s_value()

    @property
    def thermostat_momentum(self) -> float:
        """Nosé's ``pi``, eV ASE time."""
        return float(self.system.pi.floats[0])

    @property
    def tchain(self) -> int:
        """The number of thermostats in the chain (fixed at
        construction)."""
        return self.system.tchain

    @property
    def scheme(self) -> str:
        """``'velocity'`` or ``'position'`` (:func:`step_scheme`; fixed at
        construction)."""
        return self._scheme

    @property
    def thermostat_positions(self) -> tuple:
        """The chain's ``s_1, ..., s_M`` (dimensionless)."""
        return tuple(float(s.floats[0]) for s in self.system.chain_s)

    @property
    def thermostat_momenta(self) -> tuple:
        """The chain's ``pi_1, ..., pi_M``, eV ASE time."""
        return tuple(self.system.pi_values())

    @property
    def degrees_of_freedom(self) -> int:
        """``N_f``; the thermostat uses ``g = N_f + 1`` (module docstring)."""
        return self.system.degrees_of_freedom

    def get_conserved_energy(self) -> float:
        """The extended energy ``E_atoms + pi**2 / 2Q + g kT ln s``, eV,
        which the dynamics conserves but for its time-step error."""
        self._sync()
        return self.system.extended_energy()[0]

    def set_temperature(self, temperature_K):
        """Use ``temperature_K`` (K) from the next step on; the anchor
        moves here (:class:`~ase_reversible.AnchorMovedWarning` if steps
        were taken)."""
        value = checked_positive(temperature_K, 'temperature_K', 'K')
        self._change_setting('temperature',
                             lambda: self.system.set_temperature(value))

    def todict(self):
        """ASE's description plus the thermostat's settings and the
        quanta."""
        return {**super().todict(), 'temperature_K': self.temperature_K,
                'tdamp': self.tdamp, 'tchain': self.tchain, 'tloop': 1,
                'scheme': self.scheme, 'order': self.composition.order,
                'composition': self.composition.name,
                **self.system.grid.todict(),
                'force_purity': self.force_purity.mode}
