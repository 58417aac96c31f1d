"""The barostat with Nosé's thermostat: ``ReversibleIsotropicNPT(...,
thermostat='nose')``, a deterministic NPT with a conserved extended
energy (the derivation is in docs/pressure.md, "Nosé's thermostat on the
barostat").

Nosé's transformation of the barostat's Hamiltonian: the atoms' and the
piston's momenta are virtual, ``pi' = s pi`` and ``p_lambda' = s
p_lambda``, and a chain of thermostats as
:class:`~ase_reversible.ReversibleNose`'s is added.  Every term of the
Hamiltonian depends on one group of variables and moves only their
conjugates, so each is an exact shear.
"""

from __future__ import annotations

import math

import numpy as np
from ase import units

from ...core.codec import encode
from ...core.plans import SubStep
from ...core.portable import dot
from ...core.record import read_record
from ..buffered import BufferedStep
from ..nose.dynamics import (NoseChainViews, checked_tchain,
                             thermostat_start)
from ..nose.system import (CLOCK, PI, PI_KICK, S, TICK, NoseChain,
                           ThermostatDrift, Tick, chain_names, link)
from ..nose.thermostat import free_degrees_of_freedom
from .checks import checked_settings, checked_thermostat
from .isotropic import (ASE_ONLY, ENERGY_CHECK_INTERVAL,
                        ReversibleIsotropicNPT)
from .system import (DRIFT, KICK, KINETIC, LAMBDA, P_LAMBDA, PISTON, VIRIAL,
                     KineticKick, NPTHamiltonian, Piston, ScaledDrift,
                     VirialKick)

#: The piston's part of the thermostat's kick (``p_lambda'**2 / (W
#: s**3)``).
PI_PISTON = 'pi-piston'


def nose_scheme(tchain=1):
    """The sub-steps of a step, ``(name, fraction of the time step)``:
    ``B/2 C/2 T/2 A2/2 A1 A2/2 T/2 C/2 B/2`` (docs/pressure.md, "Nosé's
    thermostat on the barostat"): ``B`` the potential's kicks (of ``pi'``
    and ``p_lambda'``), ``C`` the chain's links (the last first), ``T``
    the real-time clock, ``A2`` the piston's kinetic energy (``lambda``
    and ``pi_1``), ``A1`` the atoms' kinetic energy and ``g kT ln s``
    (``rho``, ``p_lambda'`` and ``pi_1``).  A palindrome, so the same
    sequence run with ``-h`` undoes a step; one force call a step."""
    links = tuple((link(j), 0.5) for j in range(tchain, 0, -1))
    half = ((KICK, 0.5), (VIRIAL, 0.5)) + links + (
        (TICK, 0.5), (PI_PISTON, 0.5), (PISTON, 0.5), (PI_KICK, 0.5),
        (KINETIC, 0.5), (DRIFT, 0.5))
    return half + half[::-1]


class NoseNPTHamiltonian(NoseChain, NPTHamiltonian):
    """:class:`~.system.NPTHamiltonian` whose ``'momentum'`` holds ``pi' =
    s pi`` and whose ``p_lambda`` variable holds ``p_lambda' = s
    p_lambda``, with Nosé's chain (``s_j``, ``pi_j``, the clock).  The
    atoms show ``x = lambda rho`` and ``p = pi' / (lambda s)``.  Set the
    count with :meth:`count`, then the barostat and the thermostat."""

    def __init__(self, atoms, grid, counts, masses_n, project, purity):
        self.s = None
        self.tchain = 1
        super().__init__(atoms, grid, counts, masses_n, project, purity)
        self.drift = NoseScaledDrift(self)

    def count(self, degrees_of_freedom):
        """Thermostat ``degrees_of_freedom`` (``N_f``): ``g = N_f + 2``,
        the atoms' and the piston's momenta and Nosé's ``s``
        (docs/pressure.md, "Nosé's thermostat on the barostat")."""
        self.degrees_of_freedom = degrees_of_freedom
        self.g = degrees_of_freedom + 2

    def scale_value(self) -> float:
        """``lambda s``: the shown momenta are ``pi'`` divided by it."""
        s = 1.0 if self.s is None else self.s_value()
        return self.lam_value() * s

    def shown_momenta(self):
        key = (self.p.label, self.lam.label,
               None if self.s is None else self.s.label)
        if self._shown_key != key:
            np.divide(self.p.floats, self.scale_value(), out=self._shown_nc)
            self._shown_key = key
        return self._shown_nc

    def counts_of(self, positions_nc, momenta_nc):
        """``(rho, pi')`` counts (int64) of shown positions and momenta at
        the present ``lambda`` and ``s``."""
        lam = self.lam_value()
        return (encode(positions_nc / lam, self.x.quantum, 'position'),
                encode(momenta_nc * self.scale_value(), self.p.quantum,
                       'momentum'))

    def kinetic_energy(self):
        """The atoms' real kinetic energy ``sum pi'**2 / (2 m lambda**2
        s**2)``, eV."""
        ls = self.scale_value()
        return 0.5 * self.momentum_square() / (ls * ls)

    def piston_momentum(self) -> float:
        """The real ``p_lambda = p_lambda' / s``, eV ASE time."""
        return float(self.p_lam.floats[0]) / self.s_value()

    def barostat_energy(self) -> float:
        """``P V + p_lambda'**2 / (2 W s**2) - 2 kT ln lambda``, eV."""
        p = self.piston_momentum()
        return (self.pressure * self.volume() + 0.5 * p * p / self.W
                - 2.0 * self.kT * math.log(self.lam_value()))


class NoseScaledDrift(ScaledDrift):
    """``rho += round_odd(c h pi' / (m lambda**2 s**2) / q_x)``."""

    def apply(self, prepared):
        s = self.system
        ls = s.scale_value()
        self._drift(prepared, (s.p.label, s.lam.label, s.s.label,
                               prepared[0]), 1.0 / (ls * ls))

    def adjoint(self, cotangents, ch):
        """``a_pi' += c h a_rho / (m lambda**2 s**2)``; ``a_lambda -= 2 c h
        a_rho . pi' / (m lambda**3 s**2)``; ``a_s -= 2 c h a_rho . pi' /
        (m lambda**2 s**3)``."""
        cotangents.flush()
        s = self.system
        lam, s_value = s.lam_value(), s.s_value()
        ls = lam * s_value
        w_nc = np.divide(cotangents['position'], s.m_n1)
        both = 2.0 * ch / (ls * ls) * dot(w_nc, s.p.floats)
        cotangents[LAMBDA] -= both / lam
        cotangents[S] -= both / s_value
        cotangents['momentum'] += (ch / (ls * ls)) * w_nc


class NoseKinetic(KineticKick):
    """``p_lambda' += round_odd(c h 2K / lambda / q)``, ``2K = sum pi'**2
    / (m lambda**2 s**2)``: the atoms' kinetic energy pushes the piston."""

    def force(self):
        """The push ``2K / lambda`` (eV)."""
        s = self.system
        lam, s_value = s.lam_value(), s.s_value()
        return s.momentum_square() / (lam * lam * lam * (s_value * s_value))

    def apply(self, scale):
        s = self.system
        key = (s.p.label, s.lam.label, s.s.label)
        if self._key != key:
            self._force = self.force()
            self._key = key
        s.p_lam.add_rounded(scale * self._force)

    def adjoint(self, cotangents, ch):
        """``a_pi' += 2 c h a_p_lambda pi' / (m lambda**3 s**2)``;
        ``a_lambda -= 3 c h a_p_lambda M / (lambda**4 s**2)``; ``a_s -= 2
        c h a_p_lambda M / (lambda**3 s**3)``, ``M = sum pi'**2 / m``."""
        cotangents.flush()
        a = float(cotangents[P_LAMBDA][0])
        if a == 0.0:
            return
        s = self.system
        lam, s_value = s.lam_value(), s.s_value()
        push = ch * a * self.force()  # c h a M / (lambda**3 s**2)
        cotangents[LAMBDA] -= 3.0 * push / lam
        cotangents[S] -= 2.0 * push / s_value
        lam3 = lam * lam * lam
        cotangents['momentum'] += (2.0 * ch * a / (lam3 * s_value * s_value)
                                   ) * (s.p.floats / s.m_n1)


class NosePiston(Piston):
    """``lambda += round_odd(c h p_lambda' / (W s**2) / q)``."""

    def momentum(self):
        """``p_lambda' / s**2``, eV ASE time: the piston's velocity times
        ``W``."""
        s = self.system
        s_value = s.s_value()
        return float(s.p_lam.floats[0]) / (s_value * s_value)

    def adjoint(self, cotangents, ch):
        """``a_p_lambda' += c h a_lambda / (W s**2)``; ``a_s -= 2 c h
        a_lambda p_lambda' / (W s**3)``."""
        s = self.system
        a = float(cotangents[LAMBDA][0])
        s_value = s.s_value()
        cotangents[P_LAMBDA] += ch * a / (s.W * s_value * s_value)
        cotangents[S] -= 2.0 * ch * a * self.momentum() / (s.W * s_value)


class ThermostatPush(SubStep):
    """``pi_1 += round_odd(c h f / q_pi)``, ``f`` computed once per value
    of what ``key()`` names."""

    def __init__(self, system):
        self.system = system
        self._key = self._force = None

    def prepare(self, ch):
        """``c h / q_pi``."""
        return ch / self.system.pi.quantum

    def apply(self, scale):
        """``pi_1 += round_odd(scale f)``."""
        key = self.key()
        if self._key != key:
            self._force = self.force()
            self._key = key
        self.system.pi.add_rounded(scale * self._force)


class AtomsThermostatKick(ThermostatPush):
    """``pi_1 += round_odd(c h (sum pi'**2 / (m lambda**2 s**3) - g kT /
    s) / q)``: the atoms' kinetic energy and ``g kT ln s``, both functions
    of ``pi'``, ``lambda`` and ``s``."""

    def key(self):
        """The labels of ``pi'``, ``lambda`` and ``s``."""
        s = self.system
        return (s.p.label, s.lam.label, s.s.label)

    def force(self):
        """eV: ``2K / s - g kT / s``."""
        sys = self.system
        lam, s = sys.lam_value(), sys.s_value()
        return sys.momentum_square() / (lam * lam * (s * s * s)) \
            - sys.g * sys.kT / s

    def adjoint(self, cotangents, ch):
        """``a_pi' += 2 c h a_pi pi' / (m lambda**2 s**3)``; ``a_lambda -=
        2 c h a_pi M / (lambda**3 s**3)``; ``a_s += c h a_pi (g kT / s**2
        - 3 M / (lambda**2 s**4))``, ``M = sum pi'**2 / m``."""
        cotangents.flush()
        sys = self.system
        a = float(cotangents[PI][0])
        if a == 0.0:
            return
        lam, s = sys.lam_value(), sys.s_value()
        kinetic = sys.momentum_square() / (lam * lam * (s * s * s))
        cotangents[LAMBDA] -= 2.0 * ch * a * kinetic / lam
        cotangents[S] += ch * a * (sys.g * sys.kT / (s * s)
                                   - 3.0 * kinetic / s)
        cotangents['momentum'] += (2.0 * ch * a / (lam * lam * (s * s * s))
                                   ) * (sys.p.floats / sys.m_n1)


class PistonThermostatKick(ThermostatPush):
    """``pi_1 += round_odd(c h p_lambda'**2 / (W s**3) / q)``: the
    piston's kinetic energy, a function of ``p_lambda'`` and ``s``."""

    def key(self):
        """The labels of ``p_lambda'`` and ``s``."""
        s = self.system
        return (s.p_lam.label, s.s.label)

    def force(self):
        """eV: ``p_lambda'**2 / (W s**3)``."""
        sys = self.system
        p, s = float(sys.p_lam.floats[0]), sys.s_value()
        return p * p / (sys.W * (s * s * s))

    def adjoint(self, cotangents, ch):
        """``a_p_lambda' += 2 c h a_pi p_lambda' / (W s**3)``; ``a_s -= 3 c
        h a_pi p_lambda'**2 / (W s**4)``."""
        sys = self.system
        a = float(cotangents[PI][0])
        if a == 0.0:
            return
        p, s = float(sys.p_lam.floats[0]), sys.s_value()
        cotangents[P_LAMBDA] += 2.0 * ch * a * p / (sys.W * (s * s * s))
        cotangents[S] -= 3.0 * ch * a * self.force() / s


def nose_substeps(system):
    """The sub-steps of :func:`nose_scheme` but the atoms' kick, by
    name."""
    substeps = {DRIFT: system.drift, KINETIC: NoseKinetic(system),
                PISTON: NosePiston(system),
                PI_KICK: AtomsThermostatKick(system),
                PI_PISTON: PistonThermostatKick(system), TICK: Tick(system)}
    for j in range(1, system.tchain + 1):
        substeps[link(j)] = ThermostatDrift(system, j)
    return substeps


def chain_of_record(atoms, tchain, name):
    """``tchain``: that given, else that of the frame's restart record if
    the dynamics ``name`` wrote it, else 1.  Another chain than the
    record's is refused: resuming it so would silently be another run."""
    record = read_record(atoms.info, names=(), sections=('nose', 'dynamics'))
    section = record.get('nose') if record else None
    writer = record.get('dynamics') if record else None
    if section is None or not isinstance(writer, dict) \
            or writer.get('class') != name:
        return 1 if tchain is None else tchain
    written = section.get('tchain', 1)
    if tchain is not None and tchain != written:
        raise ValueError(
            f'These atoms carry the restart record of a {name} run with '
            f'tchain={written}; asked for tchain={tchain}. Leave tchain out '
            '(or pass the record\'s) to resume that run exactly, or remove '
            "the record (atoms.info.pop('reversible')) to start a new run "
            'from these atoms.')
    return written


def check_nose_arguments(name, tchain, tloop, seed, rng, buffer):
    """The arguments the Nosé thermostat refuses or takes otherwise than
    the Langevin one; returns ``tchain`` (None: the record's or 1)."""
    for arg, value in (('seed', seed), ('rng', rng), ('buffer', buffer)):
        if value is not None:
            raise TypeError(
                f"{name} with thermostat='nose' takes no {arg}: Nosé's "
                'thermostat is deterministic (no noise to seed) and runs '
                'back exactly with no buffer file. Leave it out, or pass '
                "thermostat='langevin' for the Langevin thermostat.")
    if isinstance(tloop, bool) or tloop != 1:
        raise ValueError(
            f"tloop={tloop!r}: {name} with thermostat='nose' accepts only "
            "tloop=1. ASE's MTK classes sub-cycle their chain tloop times "
            'a step; the exact chain is one Hamiltonian split into shears, '
            'with no sub-cycles. For a finer integration of the chain, use '
            'a smaller time step.')
    return checked_tchain(tchain)


def carry_names(tchain):
    """``(exact variable, key in Gradients.thermostat)`` of the barostat's
    and the chain's variables: ``'lambda'`` and ``'p_lambda'`` (the
    virtual ``p_lambda' = s p_lambda``), ``'s'``, ``'pi'``, then ``'s2'``,
    ``'pi2'``, ... for a chain."""
    names = [(LAMBDA, 'lambda'), (P_LAMBDA, 'p_lambda')]
    for j in range(1, tchain + 1):
        names += zip(chain_names(j), ('s', 'pi') if j == 1
                     else (f's{j}', f'pi{j}'))
    return names


def nose_record_section(system):
    """The restart record's ``'nose'`` section of ``system``."""
    section = {S: int(system.s.ints[0]), PI: int(system.pi.ints[0]),
               'tchain': system.tchain,
               'degrees_of_freedom': system.degrees_of_freedom}
    if system.tchain > 1:
        section['chain'] = [[int(s.ints[0]), int(pi.ints[0])]
                            for s, pi in zip(system.chain_s[1:],
                                             system.chain_pi[1:])]
    return section


def start_thermostat(system, record, timestep, temperature_K, tdamp,
                     tchain, at_rest):
    """Count ``N_f`` and set the chain: from the record's ``'nose'``
    section if it has a valid one, else ``s_j = 1``, ``pi_j = 0``.
    ``N_f = 3N - 3`` where the atoms' total momentum is held at zero
    (``at_rest``), else ``3N``."""
    section = record.get('nose') if record else None
    count = free_degrees_of_freedom(len(system.atoms),
                                    centre_at_rest=at_rest)
    if isinstance(section, dict):
        try:
            count = int(section['degrees_of_freedom'])
        except (KeyError, TypeError, ValueError):
            record['nose'] = None
    system.count(count)
    counts, quanta = thermostat_start(system, record, timestep,
                                      temperature_K, tdamp, tchain)
    system.set_thermostat(counts, quanta, temperature_K, tdamp, tchain)


class NoseBarostat(NoseChainViews):
    """What the Nosé thermostat changes in
    :class:`~.isotropic.ReversibleIsotropicNPT`'s run: the energy it
    conserves, its restart record, the real-time clock and the views of
    the chain.  Mixed in before the integrator class."""

    #: The run holds no buffer: nothing to write, no heat.
    buffer_mark = None
    keeps_buffers = False

    def _open_nose(self, system):
        self.buffered_step = BufferedStep()
        self.friction_step = None
        self._seed = None

    def _balance(self):
        energy, proposed = self.system.energy()
        system = self.system
        return (energy + system.barostat_energy()
                + system.thermostat_energy(), proposed)

    def _balance_trigger(self):
        system = self.system
        return (system.kinetic_energy() + system.barostat_energy()
                + system.thermostat_energy())

    def _explain_drift(self, number, drift, tolerance):
        return (
            f'The extended energy (atoms, P V, the piston and the Nosé '
            f'thermostat) has changed by {drift:.4g} eV since the anchor of '
            f'reversal (tolerance {tolerance:.4g} eV) after step {number}: '
            f'the integration is unstable. s is '
            f'{self.thermostat_position:.3g}. Use a smaller time step (now '
            f'{abs(self.dt) / units.fs:g} fs), a larger tdamp (now '
            f'{self.tdamp / units.fs:g} fs) or pdamp (now '
            f'{self.pdamp / units.fs:g} fs), and start nearer the target '
            'temperature. The step was not taken; the state is valid and '
            'reverse() leads back exactly. If the change is expected, raise '
            'energy_tolerance or pass energy_check=0.')

    def _record_sections(self):
        sections = super()._record_sections()
        npt = sections['npt']
        for key in ('seed', 'step'):
            npt.pop(key, None)
        sections['nose'] = nose_record_section(self.system)
        return sections

    def _encode(self, atoms, project):
        counts = super()._encode(atoms, project)
        for name, variable in self.system.variables.items():
            counts.setdefault(name, variable.ints)
        return counts

    def get_time(self):
        """Real time in ASE time units (``sum dt / s`` over the steps),
        continued from the restart record; goes back when run
        backwards."""
        return self._time0 + float(self.system.clock.floats[0])

    def write_buffer(self, path):
        """Refused: Nosé's thermostat holds no buffer; a frame's restart
        record alone resumes the run bit for bit and runs back past it."""
        raise ValueError(
            f"{type(self).__name__} with thermostat='nose' has no buffer to "
            'write: a frame (its restart record) resumes the run bit for '
            'bit and runs back past it by itself.')

    # -- gradients: the user's are on (x, p) at fixed lambda, p_lambda',
    # s and the chain; the exact variables are (rho, pi', lambda,
    # p_lambda', s, ...) with x = lambda rho and p = pi' / (lambda s).

    def _cotangents_of(self, ax_nc, ap_nc, carry):
        carried = self._carried(carry, 'barostat')
        added = self._loss_cotangents(ax_nc, ap_nc)
        cotangents = {'position': added['position'],
                      'momentum': added['momentum'], CLOCK: np.zeros(1)}
        for name, key in carry_names(self.system.tchain):
            cotangents[name] = np.array([float(carried.get(key, 0.0))])
        cotangents[LAMBDA] += added[LAMBDA]
        cotangents[S] += added[S]
        return cotangents

    def _loss_cotangents(self, ax_nc, ap_nc):
        s = self.system
        lam, s_value = s.lam_value(), s.s_value()
        n = s.x.ints.shape
        ax_nc = np.zeros(n) if ax_nc is None else np.asarray(ax_nc, float)
        ap_nc = np.zeros(n) if ap_nc is None else np.asarray(ap_nc, float)
        p_dot = dot(ap_nc, s.shown_momenta())
        return {'position': lam * ax_nc, 'momentum': ap_nc / (lam * s_value),
                LAMBDA: np.array([dot(ax_nc, s.x.floats) - p_dot / lam]),
                S: np.array([-p_dot / s_value])}

    def _gradients_of(self, cotangents):
        # Back to (x, p): dL/dx = a_rho / lambda, dL/dp = lambda s a_pi';
        # at fixed (x, p), dL/dlambda = a_lambda - a_rho . rho / lambda +
        # a_pi' . pi' / lambda and dL/ds = a_s + a_pi' . pi' / s.
        s = self.system
        lam, s_value = s.lam_value(), s.s_value()
        a_rho, a_pi = cotangents['position'], cotangents['momentum']
        pulled = dot(a_pi, s.p.floats)
        gradients = {key: float(cotangents[name][0])
                     for name, key in carry_names(s.tchain)}
        gradients['lambda'] += (pulled - dot(a_rho, s.x.floats)) / lam
        gradients['s'] += pulled / s_value
        self._retrace_end = self._retrace_key()
        return a_rho / lam, a_pi * (lam * s_value), gradients

    @property
    def thermostat(self) -> str:
        """``'nose'``."""
        return 'nose'

    @property
    def heat(self) -> float:
        """0.0: Nosé's thermostat exchanges energy with ``s`` and ``pi``,
        inside the conserved extended energy."""
        return 0.0

    @property
    def barostat_momentum(self) -> float:
        """The real ``p_lambda = p_lambda' / s``, eV ASE time."""
        return self.system.piston_momentum()

    @property
    def degrees_of_freedom(self) -> int:
        """``N_f``: ``3N - 3`` with the total momentum held at zero, else
        ``3N``; the thermostat uses ``g = N_f + 2``."""
        return self.system.degrees_of_freedom

    def get_conserved_energy(self) -> float:
        """The extended energy ``E_atoms + P V + p_lambda**2 / 2W - 2 kT
        ln lambda + pi**2 / 2Q + g kT ln s`` (and the chain's others), eV:
        conserved but for the time-step error."""
        self._sync()
        return self._balance()[0]

    def todict(self):
        """ASE's description plus the ensemble's settings and the quanta."""
        described = super().todict()
        described.pop('seed', None)
        return {**described, 'thermostat': 'nose', 'tchain': self.tchain,
                'tloop': 1}


class ReversibleIsotropicNoseNPT(NoseBarostat, ReversibleIsotropicNPT):
    """:class:`~.isotropic.ReversibleIsotropicNPT` with Nosé's thermostat:
    what ``ReversibleIsotropicNPT(..., thermostat='nose')`` constructs, a
    deterministic NPT that runs back exactly with no buffer and conserves
    :meth:`get_conserved_energy`, the counterpart of ASE's
    ``IsotropicMTKNPT`` (docs/pressure.md, "Nosé's thermostat on the
    barostat").

    Arguments as for :class:`~.isotropic.ReversibleIsotropicNPT`, except:
    ``tchain`` is taken (a chain of Nosé thermostats as
    :class:`~ase_reversible.ReversibleNose`'s; default: the record's, else
    1), ``tloop`` only as 1, and ``seed``, ``rng`` and ``buffer`` are
    refused (nothing is random, nothing is buffered).  ``tdamp`` sets the
    thermostat's masses as ASE's do (``Q_1 = g kT tdamp**2``, ``g = N_f +
    2``; ``kT tdamp**2`` for the chain's others).  The atoms' total
    momentum is held at exactly zero when they start at rest (ASE's
    ``Stationary``), and ``N_f = 3N - 3`` then; else ``N_f = 3N``.
    Steps are equal in Nosé's virtual time; :meth:`get_time` is real
    time.  :meth:`backpropagate` gives the gradients on the positions and
    momenta and, in ``.thermostat``, on ``'lambda'`` (at fixed positions
    and momenta), ``'p_lambda'`` (the virtual ``p_lambda'``), ``'s'`` (at
    fixed momenta), ``'pi'`` and the chain's ``'s2'``, ``'pi2'``, ...
    (no potential parameters); :meth:`write_buffer` is refused.  Use
    ``tchain=3``: one thermostat scales the atoms and the piston
    together and damps the volume's oscillation only slowly
    (docs/pressure.md, "A check of the ensemble with Nosé's
    thermostat").
    """

    def __init__(self, atoms, timestep, temperature_K, pressure_au, tdamp,
                 pdamp, tchain=None, pchain=None, tloop=1, ploop=None, *,
                 thermostat='nose', rng=None, seed=None, buffer=None,
                 trajectory=None, logfile=None, loginterval=1,
                 position_quantum=None, momentum_quantum=None,
                 force_purity='auto', force_noise=None,
                 energy_check=ENERGY_CHECK_INTERVAL, energy_tolerance=None,
                 **kwargs):
        name = type(self).__name__
        checked_thermostat(thermostat, 'nose', name)
        given = {**kwargs, **{arg: value for arg, value in (
            ('pchain', pchain), ('ploop', ploop)) if value is not None}}
        self._refuse_ase_only(given, {k: v for k, v in ASE_ONLY.items()
                                      if k not in ('tchain', 'tloop')})
        tchain = chain_of_record(atoms, check_nose_arguments(
            name, tchain, tloop, seed, rng, buffer), name)
        timestep, settings, energy_check, energy_tolerance = \
            checked_settings(timestep, temperature_K, pressure_au, tdamp,
                              pdamp, energy_check, energy_tolerance)
        self._nose_start = (timestep, tchain)
        plan = nose_scheme(tchain)
        system, record, section = self._barostat_system(
            atoms, plan, timestep, settings, (
                position_quantum, momentum_quantum, force_purity,
                force_noise))
        if section is None or (record or {}).get('nose') is None:
            record = None  # a new run: time from 0
        self._resumed_stress = None if record is None else \
            section.get('stress')
        self._open_nose(system)
        substep = {KICK: system.kick, **self._nose_substeps(system)}
        engine = self._buffered_engine(system, plan, substep, timestep,
                                       energy_check, energy_tolerance)
        system.show_cell()
        self._open(system, engine, record, (force_purity, force_noise),
                   timestep, trajectory=trajectory, logfile=logfile,
                   loginterval=loginterval, **kwargs)

    _system_class = NoseNPTHamiltonian
    record_sections = ('npt', 'nose')

    @staticmethod
    def _nose_substeps(system):
        """The sub-steps of :func:`nose_scheme` but the atoms' kick."""
        return {VIRIAL: VirialKick(system), **nose_substeps(system)}

    def _before_resume(self, system, record, at_rest):
        timestep, tchain = self._nose_start
        start_thermostat(system, record, timestep, system.temperature_K,
                         system.tdamp, tchain, at_rest)
