"""ReversibleNose, the integrator: Nosé's thermostat
(:mod:`~ase_reversible.md.nose.system`) run back exactly with no buffer."""

from __future__ import annotations

import warnings

import numpy as np
from ase import units

from ...core.arguments import checked_positive
from ...core.compositions import composition_for
from ...core.engine import Engine, InvariantCheck
from ...core.portable import dot
from ...core.codec import round_odd
from ...core.record import EDITED, read_record
from ...errors import AnchorMovedWarning
from ..admission import projected_momenta
from ..base import ReversibleDynamics
from ..checks import check_energy_watch, check_timestep, fixed
from ..hamiltonian import largest_kick
from .system import (CLOCK, DRIFT, KICK, PI, PI_KICK, S, SCHEME_DEFAULT,
                     SCHEMES, TICK, NoseHamiltonian, ThermostatDrift,
                     ThermostatKick, Tick, chain_names, link,
                     momentum_conserved, step_scheme)
from .thermostat import (RECOVERABLE, S_QUANTUM, chain_masses, clock_quantum,
                         pi_quantum)

#: Default length of the chain (``tchain``): the single thermostat.  A
#: chain samples a crystal better, but its coordinates wander near zero,
#: where it stops with an error unless its thermostat is slow
#: (docs/thermostats.md, "A chain of thermostats"); ASE's call with
#: ``tchain=3`` is accepted unchanged.
TCHAIN = 1

#: Default steps between checks of the extended energy.
ENERGY_CHECK_INTERVAL = 100


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


def checked_tchain(tchain):
    """``tchain`` as an int, or None if None; anything but a whole number
    from 1 raises ValueError."""
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


def thermostat_start(system, record, timestep, temperature_K, tdamp,
                     tchain=1):
    """Counts and quanta of ``s_j``, ``pi_j`` and the clock: from the
    record's ``'nose'`` section if it has one, else ``s_j = 1``,
    ``pi_j = 0``.  The clock counts from 0 (the record's time is
    added).  ``system.g`` must be counted; a ``record`` whose section
    does not describe a chain of ``tchain`` has it set to None."""
    kT = units.kB * temperature_K
    names = [name for j in range(1, tchain + 1)
             for name in chain_names(j)]
    quanta = {CLOCK: clock_quantum(timestep)}
    counts = {CLOCK: np.zeros(1, np.int64)}
    for j, Q in enumerate(chain_masses(system.g, kT, tdamp, tchain), 1):
        s_name, pi_name = chain_names(j)
        quanta[s_name] = S_QUANTUM
        quanta[pi_name] = pi_quantum(Q, kT)
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


def _warn_if_moving(system):
    """Warn if unconstrained atoms move as a whole: the thermostat then
    scales the centre's motion too, which it cannot make canonical."""
    if system.at_rest or not momentum_conserved(system.atoms,
                                                system.project):
        return
    momentum_c = system.p.floats.sum(axis=0)
    drift = 0.5 * dot(momentum_c, momentum_c) / float(system.m_n1.sum())
    warnings.warn(
        f'The atoms move as a whole (centre-of-mass kinetic energy '
        f'{drift / system.kT:.3g} kT). ReversibleNose thermostats their '
        f'{system.degrees_of_freedom} degrees of freedom, the centre\'s '
        'included, as ASE\'s NoseHooverChainNVT does; but the total '
        '(virtual) momentum is conserved, so the centre\'s kinetic energy '
        'follows s and is not canonical. For canonical frames, call '
        'ase.md.velocitydistribution.Stationary(atoms) and add '
        'ase.constraints.FixCom() before constructing it (then 3N - 3 are '
        'thermostatted and the centre stays at rest).', UserWarning,
        stacklevel=3)


def _warn_if_at_rest(system):
    """Warn if the atoms have no kinetic energy: Nosé's thermostat heats
    by scaling the momenta, and zero scaled stays zero."""
    if system.p.ints.any():
        return
    warnings.warn(
        'The atoms are at rest (every momentum is zero): Nosé\'s thermostat '
        'heats by scaling the momenta and cannot warm atoms at rest; s '
        'would fall to zero and the run stop, whatever tdamp or time step. '
        f'Give the atoms thermal momenta first, e.g. '
        f'ase.md.velocitydistribution.MaxwellBoltzmannDistribution(atoms, '
        f'temperature_K={system.temperature_K:g}) and Stationary(atoms) '
        '(or use ReversibleLangevin, which can).',
        UserWarning, stacklevel=3)


def _shows_its_frame(atoms, record, section):
    """Whether the atoms' momenta are those the frame of ``record`` (its
    ``'nose'`` section ``section``) showed, ``p' / s``: the virtual
    momentum counts stored there, or recovered as ``round_odd(p s /
    q_p)``, show them again bit for bit.  A record whose numbers cannot be
    read is left to the resume, which starts afresh from it."""
    momenta = atoms.arrays.get('momenta')
    if momenta is None:
        return True
    saved = read_record(atoms.info, names=(S,))
    try:
        s_value = float(int(section[S]) * saved[f'{S}_quantum'])
        quantum = float(record['momentum_quantum'])
        stored = section.get('virtual_momentum')
        counts = None if stored is None else np.array(
            stored, dtype=np.float64).reshape(momenta.shape)
    except (KeyError, TypeError, ValueError, OverflowError):
        return True
    if not s_value > 0.0:
        return True
    if counts is None:
        counts = round_odd(momenta * (s_value / quantum))
    return np.array_equal(np.divide(counts * quantum, s_value), momenta)


class NoseChainViews:
    """The views of a Nosé chain (``system.chain_s``, ``chain_pi``) that
    :class:`ReversibleNose` and the barostat with Nosé's thermostat
    (:class:`~ase_reversible.md.npt.nose.ReversibleIsotropicNoseNPT`)
    share."""

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
    def thermostat_positions(self) -> tuple:
        """The chain's ``s_1, ..., s_M`` (dimensionless)."""
        return tuple(float(s.floats[0]) for s in self.system.chain_s)

    @property
    def thermostat_momenta(self) -> tuple:
        """The chain's ``pi_1, ..., pi_M``, eV ASE time."""
        return tuple(self.system.pi_values())


class ReversibleNose(NoseChainViews, ReversibleDynamics):
    """Nosé's constant-temperature dynamics in fixed point, run back
    exactly with no buffer: a deterministic NVT.

    The atoms and a chain of thermostats -- coordinates ``s_j`` and
    momenta ``pi_j``, ``s = s_1`` and ``pi = pi_1`` those of the first --
    evolve under a Hamiltonian in Nosé's virtual time (derived in
    docs/thermostats.md, "The extended system, split into shears"), split
    so that every update is an exact shear.  After ``run(n)``,
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
        With a calculator attached; best with zero total momentum
        (docs/thermostats.md, "Which ensemble"), which FixCom holds
        exactly.
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
        The arrangement of a step
        (:func:`~ase_reversible.md.nose.system.step_scheme`); default: the
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
    def __init__(self, atoms, timestep, temperature_K, tdamp, tchain=None,
                 tloop=1, *, scheme=None,
                 trajectory=None, logfile=None, loginterval=1, order=2,
                 composition=None, position_quantum=None,
                 momentum_quantum=None,
                 force_purity='auto', force_noise=None,
                 energy_check=ENERGY_CHECK_INTERVAL, energy_tolerance=None,
                 **kwargs):
        _check_tloop(tloop)
        tchain = checked_tchain(tchain)
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
        system.count_centre(units.kB * temperature_K,
                            (record or {}).get('nose'))
        counts, quanta = thermostat_start(system, record, timestep,
                                          temperature_K, tdamp, tchain)
        system.set_thermostat(counts, quanta, temperature_K, tdamp, tchain)
        if record is not None and record.get('nose') is not None:
            self._resume_virtual_momenta(system, record['nose'])
        _warn_if_moving(system)
        _warn_if_at_rest(system)
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
        self._open(system, engine, record, (force_purity, force_noise),
                   timestep, trajectory=trajectory, logfile=logfile,
                   loginterval=loginterval, **kwargs)

    # -- construction -------------------------------------------------------

    def _resumable_record(self, atoms):
        record = super()._resumable_record(atoms)
        section = record.get('nose') if record else None
        if section is not None and not _shows_its_frame(atoms, record,
                                                        section):
            # Momenta changed since the frame was written (rescaled,
            # re-drawn, another dynamics): a new start the user made,
            # told by nothing, as for every dynamics (core.record.EDITED).
            self._record_unfit = EDITED
            return None
        return record

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

    def get_time(self):
        """Real time in ASE time units (``sum dt / s`` over the steps),
        continued from a restart record; goes back when run backwards."""
        return self._time0 + float(self.system.clock.floats[0])

    def _record_sections(self):
        system = self.system
        section = {S: int(system.s.ints[0]), PI: int(system.pi.ints[0]),
                   'temperature_K': system.temperature_K,
                   'tdamp': system.tdamp, 'tchain': system.tchain,
                   'scheme': self._scheme,
                   'degrees_of_freedom': system.degrees_of_freedom}
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
        thermostat = self._carried(carry, 'thermostat')
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
    def scheme(self) -> str:
        """``'velocity'`` or ``'position'``
        (:func:`~ase_reversible.md.nose.system.step_scheme`; fixed at
        construction)."""
        return self._scheme

    @property
    def degrees_of_freedom(self) -> int:
        """``N_f``; the thermostat uses ``g = N_f + 1``
        (docs/thermostats.md, "Which ensemble")."""
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
