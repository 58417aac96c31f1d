"""ReversibleIsotropicNPT: the integrator (arguments, restarts, the change
contract, gradients' mapping); the dynamics is in
:mod:`~ase_reversible.md.npt.system` and :mod:`.friction`, the derivation
in docs/pressure.md, "The derivation"."""

from __future__ import annotations

import math
import warnings

import numpy as np
from ase import units

from ...core.compositions import composition_for
from ...core.portable import dot
from ...core.record import read_record
from ...errors import MachineChangedWarning
from ..buffered import BufferedDynamics, resume_point
from ..checks import checked_friction, seed_from
from ..hamiltonian import largest_kick
from ..langevin import FrictionSettings
from ..machine import describe, digest, platform
from .friction import PistonFriction, ScaledFriction
from .system import (DRIFT, FRICTION, KICK, KINETIC, LAMBDA, LAMBDA_QUANTUM,
                     P_LAMBDA, PISTON, RECOVERABLE, VIRIAL, KineticKick,
                     NPTHamiltonian, Piston, VirialKick, p_lambda_quantum)
from .checks import (_fixed_setting, _refuse_cell, _refuse_constraints,
                     _refuse_stressless, _starts_at_rest, _warn_new_run,
                     checked_settings, checked_thermostat)

#: ``B/2 P/2 T/2 O T/2 P/2 B/2`` (docs/pressure.md, "The derivation"): a
#: palindrome, so the same sequence run with -h undoes a step.  The two
#: parts of B read ``rho`` and ``lambda`` only, the two of T ``pi`` and
#: ``lambda`` only.
SCHEME = ((KICK, 0.5), (VIRIAL, 0.5), (PISTON, 0.5), (DRIFT, 0.5),
          (KINETIC, 0.5), (FRICTION, 1.0), (KINETIC, 0.5), (DRIFT, 0.5),
          (PISTON, 0.5), (VIRIAL, 0.5), (KICK, 0.5))

#: Whether the piston has friction ``1 / pdamp`` and noise of its own (a
#: Langevin piston).
PISTON_FRICTION = True

#: Default steps between checks of the energy balance.
ENERGY_CHECK_INTERVAL = 100

#: What ASE's chain integrators take and this class has no use for.
ASE_ONLY = {
    'tchain': 'the thermostat is Langevin friction and noise on every '
              'momentum (no chain): leave tchain out',
    'pchain': 'the barostat is one piston, thermalised through the atoms '
              '(no chain): leave pchain out',
    'tloop': 'the thermostat is one exact O step per time step: leave '
             'tloop out',
    'ploop': 'the piston moves in two exact half steps per time step: '
             'leave ploop out',
    'mask': 'the cell moves as a whole (ReversibleIsotropicNPT) or in '
            'every entry (ReversibleNPT); a cell with some vectors held '
            'fixed, as in ASE\'s MaskedMTKNPT, has no exact counterpart '
            'yet: leave mask out',
}


def _settings(system):
    """The ensemble's settings a buffer file is tied to."""
    return {'temperature_K': system.temperature_K,
            'pressure_au': system.pressure, 'tdamp': system.tdamp,
            'pdamp': system.pdamp}


class ReversibleIsotropicNPT(BufferedDynamics):
    """Constant pressure and temperature (NPT) in fixed point, run back
    exactly: the counterpart of ASE's
    :class:`ase.md.nose_hoover_chain.IsotropicMTKNPT`.

    The cell is scaled uniformly by an exact piston (Andersen's barostat,
    with friction and noise of its own) and the atoms are held at
    ``temperature_K`` by Langevin friction and noise (the derivation is
    in docs/pressure.md, "The derivation").  After ``run(n)``,
    :meth:`reverse` and ``run(n)``, the scaled positions, their momenta,
    the cell's scale and its momentum and the information buffer are
    bitwise those right after the constructor; so are
    ``atoms.positions``, ``atoms.get_momenta()`` and ``atoms.cell``.  The
    atoms show the Cartesian positions, momenta and cell after every step
    observers see, so ``atoms.get_volume()``, ``atoms.get_temperature()``
    and trajectories work as with ASE's NPT.

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
        of ``pdamp``; the piston's friction is ``1 / pdamp``.
    tchain, pchain, tloop, ploop
        ASE's, in ASE's places: refused with a TypeError that says what
        to pass instead (leave them out); with ``thermostat='nose'``,
        ``tchain`` is taken and ``tloop`` as 1.
    thermostat : {'langevin', 'nose'}
        ``'langevin'`` (default): Langevin friction and noise, as below.
        ``'nose'``: a chain of Nosé thermostats, deterministic, with no
        buffer and a conserved extended energy; the object is then a
        :class:`~ase_reversible.md.npt.nose.ReversibleIsotropicNoseNPT`
        (:class:`~ase_reversible.md.npt.cell_nose.ReversibleNoseNPT` for
        :class:`~ase_reversible.ReversibleNPT`), whose docstring says
        what it takes.
    rng : numpy.random.Generator or RandomState, optional
        Used once, to draw the seed (a single draw from it), so the same
        seeded generator gives the same run; the seed drawn is recorded
        and resumes the run as one passed as ``seed`` would.  Not together
        with ``seed``.  (ASE's MTK classes are deterministic and take
        none; ASE's ``LangevinBAOAB`` does.)
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

    A frame the
    run wrote resumes it (its restart record holds the reference cell,
    ``lambda``, ``p_lambda``, their quanta and a digest of the stress);
    with the file :meth:`write_buffer` wrote, bit for bit.
    :meth:`backpropagate` gives gradients through the run.

    Raises
    ------
    TypeError
        An argument of ASE's chain integrators, an ``rng`` that is not a
        numpy generator, or bad argument types.
    ValueError
        A non-periodic cell, a calculator without stress, a non-positive
        temperature, tdamp or pdamp, a non-finite pressure, ``seed`` and
        ``rng`` both given (before anything is changed).
    UnsupportedConstraintError
        Any constraint.
    UnstableIntegrationError
        During a run: the cell collapsed (``lambda`` below
        :data:`~ase_reversible.md.npt.system.LAMBDA_MIN`) or the conserved
        energy drifted; the step was
        not taken, and the state runs back exactly.
    """

    record_sections = ('npt',)
    buffer_mark = 'pressure_au'
    _ase_counterpart = 'IsotropicMTKNPT'
    _system_class = NPTHamiltonian
    _friction_class = ScaledFriction

    @staticmethod
    def _refuse_shape(atoms):
        """Refuse a cell this dynamics cannot move (any, here)."""

    @staticmethod
    def _barostat_substeps(system):
        """The piston's sub-steps by kind."""
        return {VIRIAL: VirialKick(system), PISTON: Piston(system),
                DRIFT: system.drift, KINETIC: KineticKick(system)}

    def __new__(cls, *args, thermostat='langevin', **kwargs):
        # ASE users choose the thermostat by an argument: the Nosé one is
        # a class of its own (:mod:`.nose`), a subclass of this one.
        if thermostat == 'nose' and 'nose' not in cls.record_sections:
            cls = cls._nose_class()
        return super().__new__(cls)

    @staticmethod
    def _nose_class():
        """The class ``thermostat='nose'`` constructs."""
        from .nose import ReversibleIsotropicNoseNPT
        return ReversibleIsotropicNoseNPT

    def __init__(self, atoms, timestep, temperature_K, pressure_au, tdamp,
                 pdamp, tchain=None, pchain=None, tloop=None, ploop=None, *,
                 thermostat='langevin', rng=None, seed=None, buffer=None,
                 trajectory=None, logfile=None, loginterval=1,
                 position_quantum=None, momentum_quantum=None,
                 force_purity='auto', force_noise=None,
                 energy_check=ENERGY_CHECK_INTERVAL, energy_tolerance=None,
                 **kwargs):
        name = type(self).__name__
        checked_thermostat(thermostat, 'langevin', name)
        given = {**kwargs, **{arg: value for arg, value in (
            ('tchain', tchain), ('pchain', pchain), ('tloop', tloop),
            ('ploop', ploop)) if value is not None}}
        self._refuse_ase_only(given, ASE_ONLY)
        timestep, settings, energy_check, energy_tolerance = \
            checked_settings(timestep, temperature_K, pressure_au, tdamp,
                              pdamp, energy_check, energy_tolerance)
        friction = checked_friction(1.0 / settings[2], timestep)
        seed = seed_from(seed, rng, name)
        system, record, section = self._barostat_system(
            atoms, SCHEME, timestep, settings, (
                position_quantum, momentum_quantum, force_purity,
                force_noise))
        if section is None and record is not None:
            record = None  # a new run: time from 0
        self._friction = friction
        # Compared with this machine's stress once the integrator stands.
        self._resumed_stress = None if section is None else \
            section.get('stress')
        self._seed, step = resume_point(section, timestep, seed)
        piston = PistonFriction(system, checked_friction(
            1.0 / pdamp, timestep), system.p_lam.ints.size) \
            if PISTON_FRICTION else None
        friction_step = self._friction_class(
            system, lambda: FrictionSettings(friction, system.temperature_K,
                                             True, self._seed),
            self._step_of, piston)
        substep = {KICK: system.kick, FRICTION: friction_step,
                   **self._barostat_substeps(system)}
        engine = self._buffered_engine(system, SCHEME, substep, timestep,
                                       energy_check, energy_tolerance)
        self.friction_step = self.buffered_step = friction_step
        self._resume(engine, step, buffer, _settings(system),
                     friction_step.load)
        system.show_cell()
        self._open(system, engine, record, (force_purity, force_noise),
                   timestep, trajectory=trajectory, logfile=logfile,
                   loginterval=loginterval, **kwargs)

    # -- construction -------------------------------------------------------

    def _refuse_ase_only(self, given, advice):
        """Refuse the arguments of ASE's chain integrators in ``given`` (by
        name) that ``advice`` (by name) says what to do instead of."""
        for arg, why in advice.items():
            if arg in given:
                raise TypeError(
                    f'{type(self).__name__} takes no {arg} (an argument of '
                    f'ASE\'s {self._ase_counterpart}): {why}.')

    def _barostat_system(self, atoms, scheme, timestep, settings, grid):
        """``(system, record, section)``: the atoms checked, the system of
        ``scheme`` with the barostat set (``settings``: temperature,
        pressure, tdamp, pdamp; ``grid``: the quanta and purity as the
        user passed them), resumed from the record's ``'npt'`` section if
        it fits (``section`` then is it, else None).  The total momentum
        is held at zero if the run starts (or started) at rest."""
        name = type(self).__name__
        temperature_K, pressure_au, tdamp, pdamp = settings
        _refuse_cell(atoms, name)
        self._refuse_shape(atoms)
        _refuse_constraints(atoms, name)
        system, record = self._hamiltonian(
            atoms, largest_kick(scheme, composition_for(2, None), timestep,
                                KICK),
            *grid, system_class=self._system_class)
        _refuse_stressless(atoms, name)
        kT = units.kB * temperature_K
        spread = math.sqrt(self._system_class.barostat_mass(
            len(atoms), kT, pdamp) * kT)
        quanta = {LAMBDA: LAMBDA_QUANTUM,
                  P_LAMBDA: p_lambda_quantum(
                      atoms, system.purity, spread,
                      largest_kick(scheme, composition_for(2, None),
                                   timestep, VIRIAL))}
        cell0, counts, section = self._barostat_start(system, record,
                                                      quanta)
        system.set_barostat(cell0, counts, quanta, temperature_K,
                            pressure_au, tdamp, pdamp)
        self._before_resume(system, record, _starts_at_rest(system, section))
        if section is not None:
            section = self._resume_scaled(system, section)
        if _starts_at_rest(system, section):
            system.hold_zero_momentum()
        return system, record, section

    def _before_resume(self, system, record, at_rest):
        """What a thermostat with variables of its own sets before the
        atoms' scaled momenta are taken from a frame (none here)."""

    # -- construction -------------------------------------------------------

    def _resumable_record(self, atoms):
        # A frame of this class shows positions and momenta off the grid
        # (lambda rho, pi / lambda): its record is checked when rho and pi
        # are recovered (_resume_scaled).
        # A record with a 'nose' section holds virtual momenta: only the
        # Nosé thermostat's class resumes its 'npt' section.
        record = read_record(atoms.info, sections=(
            *self.record_sections, 'nose', 'machine'))
        if record is not None and record.get('npt') is not None and (
                record.get('nose') is None
                or 'nose' in self.record_sections):
            self._resumed_machine = record.get('machine')
            return record
        return super()._resumable_record(atoms)

    @staticmethod
    def _barostat_start(system, record, quanta):
        """``(cell0, counts, section)``: from the record's ``'npt'``
        section if it has a valid one (``quanta`` then take its quanta),
        else the atoms' cell, ``lambda = 1`` and ``p_lambda = 0``."""
        atoms, kind = system.atoms, type(system)
        counts = kind.start_counts(LAMBDA_QUANTUM)
        section = record.get('npt') if record else None
        if section is not None:
            saved = read_record(atoms.info, names=(LAMBDA, P_LAMBDA))
            size = counts[LAMBDA].size
            try:
                lam_counts = np.array(section[LAMBDA],
                                      np.int64).reshape(size)
                p_counts = np.array(section[P_LAMBDA],
                                    np.int64).reshape(size)
                cell0 = np.array(section['cell0'], dtype=float).reshape(3, 3)
            except (KeyError, TypeError, ValueError, OverflowError):
                saved = None
            if saved is not None and np.isfinite(cell0).all() \
                    and kind.valid_counts(lam_counts) and np.array_equal(
                        kind.cell_at(cell0, lam_counts
                                     * saved[f'{LAMBDA}_quantum']),
                        atoms.cell.array):
                quanta[LAMBDA] = saved[f'{LAMBDA}_quantum']
                quanta[P_LAMBDA] = saved[f'{P_LAMBDA}_quantum']
                counts = {LAMBDA: lam_counts, P_LAMBDA: p_counts}
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
        momenta = atoms.arrays.get('momenta')
        if momenta is None:
            momenta = np.zeros((len(atoms), 3))
        try:
            rho, pi = system.counts_of(atoms.positions, momenta)
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
        # Atoms changed since their frame was written (an equilibration,
        # an edit) are a new start the user made: nothing to say, as for
        # every dynamics (core.record.EDITED).
        quanta = {LAMBDA: system.lam.quantum, P_LAMBDA: system.p_lam.quantum}
        system.set_barostat(
            atoms.cell.array.copy(), type(system).start_counts(
                system.lam.quantum), quanta, system.temperature_K,
            system.pressure, system.tdamp, system.pdamp)
        rho, pi = system.counts_of(atoms.positions, momenta)
        system.x.reset(rho)
        system.p.reset(pi)
        return None

    def write_buffer(self, path):
        """Write what reversal through this point needs to ``path`` (NumPy
        ``.npz``), as :meth:`ase_reversible.ReversibleLangevin.write_buffer`
        does: a frame written now and this file restart the run bit for
        bit (``ReversibleIsotropicNPT(frame, ..., buffer=path)``), and
        the restarted run goes back past the restart point."""
        # The machine is checked through the frame's record (the stress's
        # digest), not the file.
        self._save_buffer(path, {**_settings(self.system),
                                 **self.friction_step.arrays()},
                          machine=False)

    def _check_machine(self, section):
        same = super()._check_machine(section)
        recorded = self._resumed_stress
        if recorded is None or same is False:
            return same
        if digest(self.system.kick.stress()) == recorded:
            return same
        dropped = self.engine.anchor_index != self.engine.step_index
        if dropped:
            self._install(self.engine.snapshot())
        else:
            self._write_frame_record()
        there = section.get('platform') if isinstance(section, dict) \
            else None
        warnings.warn(
            f'The stress at this restart frame (time '
            f'{self.get_time() / units.fs:.6g} fs) differs from the one the '
            'run that wrote it computed there'
            + ('' if same else ' (its forces were not compared)')
            + ': the piston is pushed otherwise on this machine. Written '
            f'on: {describe(there) if there else "unknown"}. Here: '
            f'{describe(platform(self.atoms.calc))}. The run from this '
            'frame is exact and reverses exactly to it; running back past '
            'it is not to be trusted to reach the earlier states of the '
            'run that wrote it'
            + ('; the way back the buffer file held was dropped' if dropped
               else '')
            + '. Run on the machine and software stack that wrote it '
            '(same CPU features, numpy, BLAS and thread counts) to go '
            'back past it.', MachineChangedWarning, stacklevel=4)
        return False

    # -- what the steps read ------------------------------------------------

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

    def _record_sections(self):
        system, engine = self.system, self.engine
        section = {LAMBDA: system.record_counts(system.lam),
                   P_LAMBDA: system.record_counts(system.p_lam),
                   'cell0': system.cell0.reshape(-1).tolist(),
                   'temperature_K': system.temperature_K,
                   'pressure_au': system.pressure, 'tdamp': system.tdamp,
                   'pdamp': system.pdamp, 'seed': self._seed,
                   'step': engine.step_index, 'timestep': abs(engine.dt)}
        if system.centre is not None:
            section['zero_momentum'] = True
        stress = system.kick.held_stress()
        if stress is not None:
            # Checked on resume as the forces are (:mod:`..machine`): a
            # BLAS product in the calculator's stress may change its bits
            # on another machine when its forces do not.
            section['stress'] = digest(stress)
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
                f'{type(self).__name__}, which moves the cell itself (to '
                f'{cell.tolist()}): the change is refused. The cell, '
                'positions and momenta were put back to the exact state '
                f'at time {self.get_time() / units.fs:.6g} fs, from which '
                'reverse() and further runs go on. To start from another '
                f'cell, construct a new {type(self).__name__}.')
        _refuse_constraints(atoms, type(self).__name__)
        if atoms.calc is not None and atoms.calc is not self._watch.calc:
            _refuse_stressless(atoms, type(self).__name__)
        return super()._take_changes(changes)

    def _encode(self, atoms, project):
        system = self.system
        momenta = atoms.arrays.get('momenta')
        if momenta is None:
            momenta = np.zeros((len(atoms), 3))
        rho, pi = system.counts_of(atoms.positions, momenta)
        if system.centre is not None:
            pi = system.centre.balanced_counts(pi)
        return {'position': rho, 'momentum': pi,
                LAMBDA: system.lam.ints, P_LAMBDA: system.p_lam.ints}

    def _install(self, counts):
        super()._install(counts)
        self.system.show_cell()

    # -- gradients ----------------------------------------------------------

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
        barostat = self._carried(carry, 'barostat')
        added = self._loss_cotangents(ax_nc, ap_nc)
        size = self.system.lam.ints.size
        return {'position': added['position'],
                'momentum': added['momentum'],
                LAMBDA: added[LAMBDA] + np.asarray(
                    barostat.get('lambda', 0.0), float).reshape(-1),
                P_LAMBDA: np.zeros(size) + np.asarray(
                    barostat.get('p_lambda', 0.0), float).reshape(-1)}

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

    # -- the ensemble --------------------------------------------------------

    temperature_K = _fixed_setting(
        'temperature_K', 'temperature_K',
        'Target temperature, K (fixed at construction).')
    pressure_au = _fixed_setting(
        'pressure_au', 'pressure',
        'Target pressure, eV/Å**3 (fixed at construction).')
    tdamp = _fixed_setting(
        'tdamp', 'tdamp',
        'The thermostat\'s time, ASE time units (friction ``1 / tdamp``).')
    pdamp = _fixed_setting('pdamp', 'pdamp',
                           'The barostat\'s time, ASE time units.')

    @property
    def thermostat(self) -> str:
        """``'langevin'`` (``'nose'`` for the class ``thermostat='nose'``
        constructs)."""
        return 'langevin'

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
        """``W``, eV (ASE time)**2 (see docs/pressure.md, "The derivation")."""
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
