"""Nosé's extended Hamiltonian in fixed point: the atoms with a chain of
thermostats, and the sub-steps (shears) a step is made of.  The
equations are derived in docs/thermostats.md ("The extended system,
split into shears", "A chain of thermostats")."""

from __future__ import annotations

import math

import numpy as np
from ase import units

from ...core.codec import round_odd
from ...core.plans import SubStep
from ...core.portable import dot
from ...core.variables import ExactVariable
from ...errors import QuantumRangeError, UnstableIntegrationError
from ..constraints import ADDED_FORCES, no_projection
from ..hamiltonian import Drift, Hamiltonian
from .thermostat import (chain_masses, confinement, confinement_curvature,
                         confinement_force, centre_at_rest,
                         free_degrees_of_freedom)

S, PI, CLOCK = 'thermostat_position', 'thermostat_momentum', 'time'
DRIFT, KICK, S_DRIFT, PI_KICK, TICK = ('drift', 'kick', 's-drift',
                                       'pi-kick', 'tick')


def link(j):
    """The name of the sub-step that moves ``s_j`` (``j`` from 1)."""
    return S_DRIFT if j == 1 else f'{S_DRIFT}-{j}'


def chain_names(j):
    """The names of ``s_j`` and ``pi_j`` (``j`` from 1): the first link
    keeps the names of the single thermostat."""
    return (S, PI) if j == 1 else (f'{S}_{j}', f'{PI}_{j}')


def step_scheme(kind='velocity', tchain=1):
    """The sub-steps of a step, ``(name, fraction of the time step)``.

    ``'velocity'``: ``B/2 C/2 A C/2 B/2`` (docs/thermostats.md, "The
    extended system, split into shears"): the forces at the step's end,
    and the thermostat's kicks reading the momenta half kicked.
    ``'position'``: ``A/2 C/2 B C/2 A/2``: the force call in the middle of
    the step (``B`` and ``C`` commute), and the thermostat's kicks reading
    the momenta at the step's ends, those the frames show; the
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


def momentum_conserved(atoms, project):
    """Whether the forces and constraints conserve the atoms' total
    momentum: no projection (FixCom holds it at zero by its own count) and
    no Hookean spring to a point or plane (one between two atoms pulls
    both equally)."""
    return project is no_projection and not any(
        isinstance(c, ADDED_FORCES) and getattr(c, '_type', None)
        != 'two atoms' for c in atoms.constraints)


def degrees_of_freedom(atoms, project, centre_held=False):
    """``N_f``: the free momentum coordinates as ASE counts them
    (``atoms.get_number_of_degrees_of_freedom()``: ``3N`` less what
    FixAtoms, FixCartesian, FixedPlane and FixedLine remove), less one per
    Cartesian component with a free coordinate under FixCom (its total
    momentum is held at zero).  Free atoms count ``3N`` even when their
    centre is at rest, as ASE's ``NoseHooverChainNVT`` thermostats them.
    ``centre_held``: less 3 more for free atoms whose centre is at rest,
    the count a restart record without ``'degrees_of_freedom'`` was
    written with (:meth:`NoseHamiltonian.count_centre`)."""
    n_atoms = len(atoms)
    if project is no_projection:
        return free_degrees_of_freedom(n_atoms, centre_at_rest=centre_held)
    trace = 0.0
    for c in range(3):
        unit_nc = np.zeros((n_atoms, 3))
        unit_nc[:, c] = 1.0
        project(unit_nc)
        trace += float(unit_nc[:, c].sum())
    centre = getattr(project, 'centre', None)
    held = 0 if centre is None else centre.components
    return int(round(trace)) - held


class NoseChain:
    """The chain of Nosé thermostats a system carries (``s_j``, ``pi_j``,
    their masses ``Q_j`` and the real-time clock): what
    :class:`NoseHamiltonian` and the barostat's Nosé system
    (:class:`~ase_reversible.md.npt.nose.NoseNPTHamiltonian`) share.  The
    system sets ``g`` (the thermostat's count) before
    :meth:`set_thermostat`."""

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

    def _set_mass(self):
        self.masses_Q = chain_masses(self.g, self.kT, self.tdamp,
                                     self.tchain)
        self.Q = self.masses_Q[0]

    def s_value(self) -> float:
        """``s``, its exact float image."""
        return float(self.s.floats[0])

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


class NoseHamiltonian(NoseChain, Hamiltonian):
    """The atoms with Nosé's thermostat: ``'momentum'`` holds the virtual
    momenta ``p' = s p``, the atoms show ``p = p' / s``; ``s``, ``pi`` and
    the real time are exact variables of shape ``[1]``.

    Parameters as for :class:`~.hamiltonian.Hamiltonian`; the thermostat is
    set with :meth:`set_thermostat`.
    """

    def __init__(self, atoms, grid, counts, masses_n, project, purity):
        self.kT = self.tdamp = None
        self.tchain = 1
        #: Whether the centre of mass started at rest (:meth:`count_centre`).
        self.at_rest = True
        #: Whether ``N_f`` leaves out a centre at rest (a record's count).
        self.centre_held = False
        super().__init__(atoms, grid, counts, masses_n, project, purity)
        self.drift = ScaledDrift(self)
        self._shown_nc = np.empty(self.p.ints.shape)
        self._shown_key = None

    def set_dynamics(self, masses_n, project, purity):
        super().set_dynamics(masses_n, project, purity)
        self._count()

    def count_centre(self, kT, section=None):
        """Decide, once, from the momenta at the start, whether the centre
        of mass is at rest at ``kT`` (eV), and count ``N_f`` and ``g =
        N_f + 1``.  ``section``: the restart record's ``'nose'`` section
        being resumed, if any.  Records that do not carry
        ``'degrees_of_freedom'`` were written when a centre at rest was
        left out of ``N_f``; resuming them so keeps their runs exact."""
        # From the counts: their sum is exact, the same on every machine.
        self.at_rest = centre_at_rest(
            self.p.ints.sum(axis=0) * self.p.quantum,
            float(self.m_n1.sum()), kT)
        self.centre_held = (
            isinstance(section, dict)
            and 'degrees_of_freedom' not in section and self.at_rest
            and momentum_conserved(self.atoms, self.project))
        self._count()

    def _count(self):
        self.degrees_of_freedom = degrees_of_freedom(
            self.atoms, self.project, self.centre_held)
        if self.degrees_of_freedom < 1:
            raise ValueError('ReversibleNose needs at least one free degree '
                             'of freedom; every momentum is constrained.')
        self.g = self.degrees_of_freedom + 1
        if self.kT is not None:
            self._set_mass()

    # -- what the atoms show ----------------------------------------------

    def shown_momenta(self):
        return self.divided_momenta(self.s)

    def virtual_counts(self, momenta_nc, s_value):
        """The virtual momentum counts ``rint(p s / q_p)`` of real momenta
        ``momenta_nc`` ``[n_atoms, 3]`` (projected) at ``s``."""
        y_nc = momenta_nc * (s_value / self.p.quantum)
        if self.centre is not None:
            # FixCom: zero total, as the drift and kick keep it.
            self.centre.balance(round_odd(y_nc, out=y_nc))
        return round_odd(y_nc).astype(np.int64)

    # -- energies ---------------------------------------------------------

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


#: Kinetic temperature, as a fraction of the target, below which ``s``
#: falling to zero is blamed on atoms too cold to be warmed by scaling.
COLD = 0.1


def _cold_atoms(system):
    """The cause and remedy of ``s`` at zero if the atoms' kinetic
    temperature is below :data:`COLD` of the target, else ''."""
    kinetic_K = (2.0 * system.kinetic_energy()
                 / (system.degrees_of_freedom * units.kB))
    if not kinetic_K < COLD * system.temperature_K:
        return ''
    return (
        f'the atoms are (nearly) at rest ({kinetic_K:.3g} K against the '
        f'target {system.temperature_K:g} K). Nosé\'s thermostat heats by '
        'scaling the momenta, which cannot warm atoms at rest, whatever '
        'tdamp or time step. Give the atoms thermal momenta first, e.g. '
        'ase.md.velocitydistribution.MaxwellBoltzmannDistribution(atoms, '
        f'temperature_K={system.temperature_K:g}) and Stationary(atoms) '
        '(or thermalize with ReversibleLangevin first). The step was not '
        'taken; the state is valid and reversible.')


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
            cold = _cold_atoms(sys)
            if cold:
                name = 's' if sys.tchain == 1 else f's_{j}'
                raise UnstableIntegrationError(
                    f'The Nosé thermostat coordinate {name} reached zero: '
                    f'{cold}')
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
