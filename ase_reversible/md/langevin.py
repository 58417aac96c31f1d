"""ReversibleLangevin: constant-temperature dynamics that runs back exactly.

Langevin dynamics split as BAOAB (B. Leimkuhler and C. Matthews, "Rational
construction of stochastic numerical methods for molecular sampling",
AMRX 2013): kick ``h/2``, drift ``h/2``, the Ornstein-Uhlenbeck step
``p <- c p + sqrt((1 - c**2) m kT) xi`` with ``c = exp(-gamma h)``, drift
``h/2``, kick ``h/2``.  Kicks and drifts are the exact shears of
:mod:`.hamiltonian`.  The O step is made exact in two parts:

* friction, multiplication of the momentum counts by ``c``, drops
  information; it is done exactly by an information buffer
  (:mod:`ase_reversible.core.infobuffer`) that keeps the dropped digits,
  ``-log2(c)`` bits per coordinate per step, and gives them back on the
  way back;
* the noise ``rint(sqrt((1 - c**2) m kT) xi / q_p)`` is an integer drawn
  from a counter-based generator keyed by the seed, the time step and the
  step's index (:mod:`ase_reversible.core.noise`), so the way back
  subtracts the same integers without storing any.

``c`` is used as the ratio ``n / 2**16`` nearest to it, and the noise
amplitude is computed from that ratio, so the O step samples the
Maxwell-Boltzmann distribution exactly for the friction
``-ln(n / 2**16) / h`` (:attr:`ReversibleLangevin.effective_friction`,
within 2**-17 / h of the one asked for).
"""

from __future__ import annotations

import functools
import warnings
from typing import NamedTuple

import numpy as np
from ase import units

from ..core.compositions import composition_for
from ..core.infobuffer import (DIGIT_BITS, BufferUnderflowError,
                               InformationBuffer, friction_ratio)
from ..core.noise import StepNoise, step_key
from ..core import portable
from ..errors import AnchorMovedWarning, RetraceLimitError
from .buffered import (BufferedDynamics, BufferedMomentumStep, buffer_arrays,
                       load_buffer_arrays, resume_point)
from .checks import (check_energy_watch, check_temperature_K,
                     check_timestep, checked_friction,
                     refuse_plane_and_line_constraints, seed_from)
from .hamiltonian import largest_kick

DRIFT, KICK, FRICTION = 'drift', 'kick', 'friction'

#: BAOAB: a palindrome, so the same sequence run with -h undoes a step.
SCHEME = ((KICK, 0.5), (DRIFT, 0.5), (FRICTION, 1.0), (DRIFT, 0.5),
          (KICK, 0.5))

#: Default steps between checks of the energy balance.
ENERGY_CHECK_INTERVAL = 100


class FrictionSettings(NamedTuple):
    """What the O step reads of its dynamics when a step is prepared."""

    #: 1 / ASE time unit (0: no thermostat).
    friction: float
    #: K.
    temperature_K: float
    #: Whether the noise has zero net momentum.
    fixcm: bool
    #: The key of the noise.
    seed: int


class FrictionPlan(NamedTuple):
    """One O step at a coefficient ``ch``, as :meth:`Friction.prepare`
    makes it (a coordinate index ``k`` runs over ``3 n_atoms``)."""

    #: ``ch > 0``.
    forward: bool
    #: The information buffer of the step's friction ratio.
    buffer: InformationBuffer
    #: bool ``[3 n_atoms]`` of the coordinates moved, None for all.
    mask_k: object
    #: float ``[3 n_atoms]``: the noise's spread, in momentum counts.
    sigma_k: np.ndarray
    #: The Philox key of the step's noise.
    key: np.ndarray
    #: ``(weights_nc, heaviest_c)`` that zero the noise's net momentum,
    #: or None.
    zero_sum: object
    #: float ``[3 n_atoms]``: ``1 / m`` for the heat (1 / amu).
    inverse_mass_k: np.ndarray
    #: The coordinates FixCom holds, ``[(atom, component)]``, or None.
    held: object


class Friction(BufferedMomentumStep):
    """The O step on the momentum counts, exact (see the module docstring):
    a :class:`~.buffered.BufferedMomentumStep` whose ``settings()`` returns
    :class:`FrictionSettings`, with an :class:`InformationBuffer` per
    friction ratio used since the anchor; ``heat`` is the kinetic energy
    the O steps added since then (eV): the total energy minus it is what
    the integrator conserves.

    Under FixCom (``system.centre``) the total momentum stays exactly
    zero: the noise has its sum removed in proportion to mass, and the
    friction acts through the buffer on every free coordinate but one per
    Cartesian component, whose momentum is then minus the others' sum --
    still a bijection, since the others determine it both ways.  With no
    friction the step does nothing.
    """

    def __init__(self, system, settings, step_of):
        super().__init__(system, settings, step_of)
        self.noise = StepNoise(self.size)

    def load(self, saved):
        """Take the buffers of a file :meth:`ReversibleLangevin.write_buffer`
        wrote (``saved``: its arrays by name)."""
        load_buffer_arrays('buffer', self.buffers, saved, lambda n: (
            'The buffer file was written with another friction (exact '
            f'ratio {n}/2**16, here {", ".join(map(str, self.buffers))}'
            '/2**16): construct with the friction and time step of the '
            'run that wrote it.'))

    def prepare(self, ch):
        friction, temperature_K, fixcm, seed = self.settings()
        if friction == 0:
            return None  # NVE: c = 1 and no noise, nothing to do or store
        s = self.system
        n, ratio = exact_ratio(friction, ch)
        buffer = self.buffers.get(n)
        if buffer is None:
            buffer = self.buffers[n] = InformationBuffer(self.size, n)
        free_k = self.free_k()
        mass_k = self.mass_k()
        sigma_k = np.sqrt((1.0 - ratio * ratio) * mass_k * units.kB
                          * temperature_K) / self.quantum_k() * free_k
        zero_sum = _zero_sum_weights(s.m_n1, self._free()) \
            if fixcm or s.centre is not None else None
        held = self._hold_one_per_component(free_k)
        return FrictionPlan(ch > 0, buffer, None if free_k.all() else free_k,
                            sigma_k, step_key(seed, ch), zero_sum,
                            self.inverse_mass_k(), held)

    def apply(self, prepared):
        if prepared is None:
            return
        forward, buffer, mask_k, sigma_k, key, zero_sum, inverse_mass_k, \
            held = prepared
        x_k = self.counts_k()
        noise_k = np.rint(sigma_k * self.noise.normals(key, self.step_of()))
        noise_k = noise_k.astype(np.int64)
        if zero_sum is not None:
            # The momenta's part: the bodies' spins carry no momentum.
            atoms_k = zero_sum[0].size
            noise_k[:atoms_k] = without_net_momentum(noise_k[:atoms_k],
                                                     *zero_sum)
        new_k = exact_o_step(buffer, x_k, noise_k, forward, mask_k, (
            'ReversibleLangevin can only retrace steps it has taken: this '
            'one goes back past the anchor of reversal, where friction '
            'would have to be undone that was never applied. The step was '
            'not taken; run forward (positive dt) from here.'))
        self._commit(x_k, new_k, held, inverse_mass_k)

    def adjoint(self, cotangents, ch):
        """The O step is affine in the momenta with slope ``c``: ``a_p *=
        c`` on the coordinates it moves (the noise does not depend on the
        state), after the pending kicks."""
        cotangents.flush()
        ratio = exact_ratio(self.settings().friction, ch)[1]
        cotangents['momentum'] *= np.where(self._free() != 0, ratio, 1.0)
        if self.parts:  # rigid bodies' spins, with a moment
            cotangents['angular_momentum'] *= np.where(
                self.parts[0][1].reshape(-1, 3) > 0, ratio, 1.0)


def exact_o_step(buffer, x_k, noise_k, forward, mask_k, past_the_anchor):
    """The O step's new counts (int64 ``[k]``): ``c x + noise`` going
    forward (``c`` through ``buffer``, an InformationBuffer), its inverse
    ``(x - noise) / c`` going back.  ``mask_k`` (bool, or None for all)
    leaves the other coordinates as they are.  A step back past the
    anchor raises RetraceLimitError with the message
    ``past_the_anchor``."""
    if forward:
        return buffer.scale_down(x_k, mask_k) + noise_k
    try:
        return buffer.scale_up(x_k - noise_k, mask_k)
    except BufferUnderflowError:
        raise RetraceLimitError(past_the_anchor) from None


# The software exp costs 4 us (idle; 19 us under load) and a retrace asks
# for the ratio at every step: cached, 0.1 us.
@functools.lru_cache(maxsize=16)
def exact_ratio(friction, ch):
    """``(n, n / 2**16)``: the exact friction factor of a step of ``ch``
    (ASE time units, either sign) at ``friction`` (1 / ASE time unit);
    ``(2**16, 1.0)`` for no friction.

    ``n`` decides bits of the momenta.  A libm's ``exp`` may differ
    between machines in its last bit (glibc's missed the correctly rounded
    value in 78 of 100,000 arguments in ``[-11, 0)``, measured), which
    moves ``n`` where ``2**16 exp(-friction |ch|)`` lies within ``2**16``
    times that bit (~1.5e-11) of a half: the exponential is computed in
    software, the same everywhere
    (:func:`ase_reversible.core.portable.exp`, 19 µs, once per time
    step).
    """
    if friction == 0:
        return 1 << DIGIT_BITS, 1.0
    n = friction_ratio(portable.exp(-friction * abs(ch)))
    return n, n / 2**DIGIT_BITS


def _zero_sum_weights(m_n1, free_nc):
    """``(weights_nc, heaviest_c)`` that spread a net momentum over the free
    coordinates in proportion to mass, or None if a component has no free
    coordinate."""
    mass_nc = m_n1 * (free_nc != 0)
    total_c = mass_nc.sum(axis=0)
    if not np.all(total_c > 0):
        return None
    return mass_nc / total_c, np.argmax(mass_nc, axis=0)


def without_net_momentum(noise_k, weights_nc, heaviest_c):
    """The integer noise with its sum over atoms made exactly zero in each
    Cartesian component, removed in proportion to mass (rounded; the
    heaviest free atom takes what rounding leaves)."""
    noise_nc = noise_k.reshape(weights_nc.shape)
    net_c = noise_nc.sum(axis=0)
    share_nc = np.rint(weights_nc * net_c).astype(np.int64)
    share_nc[heaviest_c, np.arange(3)] += net_c - share_nc.sum(axis=0)
    return (noise_nc - share_nc).reshape(-1)


class ReversibleLangevin(BufferedDynamics):
    """Langevin dynamics (NVT) in fixed point that can be run back exactly.

    A drop-in for :class:`ase.md.langevin.Langevin`: the same thermostat
    (friction and noise on every momentum), split as BAOAB.  After
    ``run(n)``, :meth:`reverse` and ``run(n)`` positions, momenta and the
    information buffer are bitwise those right after the constructor --
    the noise is subtracted again and the friction undone from the digits
    it dropped (module docstring).  The way back cannot go further than
    that: there is no friction to undo before the anchor
    (:class:`~ase_reversible.RetraceLimitError`).

    Parameters
    ----------
    atoms : ase.Atoms
        With a calculator attached.
    timestep : float
        ASE time units (``5 * ase.units.fs``).
    temperature_K : float
        Target temperature, K, in ASE's third place or as a keyword
        (required).  ASE's deprecated ``temperature`` in eV is refused with
        its value in K, whether as ``temperature=`` or positionally (a
        value below 1: ``ReversibleLangevin(atoms, dt, 300 * units.kB,
        friction)`` says to pass ``temperature_K=300``).
    friction : float
        Friction coefficient, 1 / ASE time unit (``0.01 / ase.units.fs``);
        ``friction * |timestep|`` may be at most 11 (``c >= 2**-16``).
        0 turns the thermostat off: no friction, no noise, an empty
        buffer (constant-energy dynamics that also runs back past its
        start).
    fixcm : bool
        If True (default), the random kicks have exactly zero net
        momentum, so a system at rest stays at rest (the friction's
        rounding, below a hundred momentum quanta per atom and step, is
        all that moves the centre of mass).  ASE 3.29 deprecates its
        ``fixcm=True`` for ``fixcm=False`` with ``ase.constraints.FixCom``;
        FixCom here holds the total momentum at exactly zero, friction
        included (:class:`Friction`), whatever ``fixcm`` says.
    rng : numpy.random.Generator or RandomState, optional
        As ASE's: used once, to draw the seed (a single draw from it), so
        the same seeded generator gives the same run; the seed drawn is
        recorded and resumes the run as one passed as ``seed`` would.
        Not together with ``seed``.
    seed : int, optional
        Key of the noise, stored as ``seed``
        (:attr:`~ase_reversible.md.buffered.BufferedDynamics.seed`).
        Default: the seed in the atoms' restart record if it was written
        at this time step (a frame of an earlier run goes on with its
        noise), else drawn from the operating system.  The same seed and
        start give the same run.
    buffer : str or path, optional
        A file :meth:`write_buffer` wrote together with the frame these
        atoms come from: the run then goes on bit for bit as the one that
        wrote it, and runs back past this point.  Without it, a frame goes
        on with the same noise but not the same bits (see
        :meth:`write_buffer`).
    trajectory, logfile, loginterval
        As for :class:`ase.md.langevin.Langevin`.
    position_quantum, momentum_quantum, force_purity, force_noise
        As for :class:`~ase_reversible.ReversibleVerlet`.
    energy_check : int
        As for :class:`~ase_reversible.ReversibleVerlet`, for the total
        energy minus the heat the thermostat added since the anchor
        (``heat``, :attr:`~ase_reversible.md.buffered.BufferedDynamics.heat`),
        which BAOAB conserves but for its time-step error.
    energy_tolerance : float, optional
        eV; default as for :class:`~ase_reversible.ReversibleVerlet`.
    **kwargs
        Passed to :class:`ase.md.md.MolecularDynamics`.

    ASE's ``temp`` (eV), ``set_temperature``, ``set_friction`` and
    ``set_timestep`` are there, with ASE's names and units.

    Raises
    ------
    TypeError
        ``temperature=`` (ASE's eV), an ``rng`` that is not a numpy
        generator, or bad argument types.
    ValueError
        A non-positive temperature or one below 1 K (eV), ``seed`` and
        ``rng`` both given, a negative friction, or ``friction *
        |timestep|`` beyond 11 or too small to change a momentum.
    UnsupportedConstraintError
        A constraint other than FixAtoms, FixCartesian and FixCom.
    """

    record_sections = ('langevin',)
    rigid_bodies = rigid_adjoint = True

    def __init__(self, atoms, timestep, temperature_K=None, friction=None,
                 fixcm=True, *, temperature=None, rng=None, seed=None,
                 buffer=None, trajectory=None,
                 logfile=None, loginterval=1, position_quantum=None,
                 momentum_quantum=None,
                 force_purity='auto', force_noise=None,
                 energy_check=ENERGY_CHECK_INTERVAL, energy_tolerance=None,
                 **kwargs):
        timestep = check_timestep(timestep)
        self._temperature_K = check_temperature_K(
            temperature_K, 'ReversibleLangevin', temperature)
        seed = seed_from(seed, rng, 'ReversibleLangevin')
        if friction is None:
            raise TypeError(
                'ReversibleLangevin needs friction, 1 / ASE time unit (e.g. '
                'friction=0.01 / ase.units.fs, as for ASE\'s Langevin).')
        self._friction = checked_friction(friction, timestep)
        self._fixcm = bool(fixcm)
        energy_check, energy_tolerance = check_energy_watch(
            energy_check, energy_tolerance)
        refuse_plane_and_line_constraints(atoms)
        system, record = self._hamiltonian(
            atoms, largest_kick(SCHEME, composition_for(2, None), timestep,
                                KICK),
            position_quantum, momentum_quantum,
            force_purity, force_noise)
        self._seed, step = resume_point(
            record.get('langevin') if record else None, timestep, seed)
        friction_step = Friction(system, self._settings, self._step_of)
        substep = {KICK: system.kick, DRIFT: system.drift,
                   FRICTION: friction_step}
        engine = self._buffered_engine(system, SCHEME, substep, timestep,
                                       energy_check, energy_tolerance)
        self.friction_step = self.buffered_step = friction_step
        # A file from before the settings were written has none.
        self._resume(engine, step, buffer,
                     {'temperature_K': self._temperature_K,
                      'friction': self._friction}, friction_step.load,
                     settings_optional=True)
        self._open(system, engine, record, (force_purity, force_noise),
                   timestep, trajectory=trajectory, logfile=logfile,
                   loginterval=loginterval, **kwargs)

    # -- what the friction step reads ------------------------------------

    def _settings(self):
        return FrictionSettings(self._friction, self._temperature_K,
                                self._fixcm, self._seed)

    def _take_changes(self, changes):
        # A plane or line set between runs is refused as at construction.
        refuse_plane_and_line_constraints(self.atoms)
        return super()._take_changes(changes)

    def _record_sections(self):
        return {'langevin': {'seed': self._seed,
                             'step': self.engine.step_index,
                             'timestep': abs(self.engine.dt)}}

    def write_buffer(self, path):
        """Write what reversal through this point needs to ``path`` (NumPy
        ``.npz``): the information buffer, the anchor of reversal and the
        step, tied to the present state by a digest.

        A frame written now (the atoms hold it) and this file make a
        restart that continues bit for bit and runs back past the restart
        point to the anchor: ``ReversibleLangevin(frame, dt, T, friction,
        buffer=path)``.  The frame alone continues with the same noise but
        a fresh buffer, whose digits enter the friction's rounding: the
        same statistics, not the same bits, and no way back past it.
        """
        # The way back past the frame draws the noise again: at the
        # temperature and friction it was drawn with, or it misses.
        self._save_buffer(path, {
            'temperature_K': self._temperature_K, 'friction': self._friction,
            **buffer_arrays('buffer', self.friction_step.active_buffers())})

    # -- the thermostat's settings -----------------------------------------

    @property
    def temperature_K(self) -> float:
        """Target temperature, K (change it with :meth:`set_temperature`)."""
        return self._temperature_K

    @property
    def temp(self) -> float:
        """Target ``kB T``, eV: ASE's ``Langevin.temp``."""
        return units.kB * self._temperature_K

    @property
    def friction(self) -> float:
        """Friction coefficient asked for, 1 / ASE time unit (change it
        with :meth:`set_friction`)."""
        return self._friction

    @property
    def effective_friction(self) -> float:
        """The friction the O step applies, 1 / ASE time unit:
        ``-ln(n / 2**16) / |dt|`` for the exact ratio ``n / 2**16``
        nearest to ``exp(-friction |dt|)``."""
        return -portable.log(exact_ratio(self._friction, self.dt)[1]) \
            / abs(self.dt) if self._friction else 0.0

    @property
    def fixcm(self) -> bool:
        """Whether the noise has zero net momentum (fixed at construction)."""
        return self._fixcm

    def set_temperature(self, temperature_K=None, *, temperature=None):
        """Use ``temperature_K`` (K) from the next step on.  Steps before
        cannot be retraced with it: the anchor moves here
        (:class:`~ase_reversible.AnchorMovedWarning` if steps were taken).
        ASE's ``temperature`` in eV is refused with its value in K, as a
        keyword or positionally (a value below 1), as by the constructor."""
        value = check_temperature_K(temperature_K, 'ReversibleLangevin',
                                    temperature)
        self._change_setting('temperature', lambda: setattr(
            self, '_temperature_K', value))

    def set_friction(self, friction):
        """Use ``friction`` (1 / ASE time unit) from the next step on; the
        anchor moves here, as for :meth:`set_temperature`."""
        value = checked_friction(friction, self.dt)
        self._change_setting('friction',
                             lambda: setattr(self, '_friction', value))

    def set_timestep(self, timestep):
        """ASE's ``Langevin.set_timestep``: the time step (ASE time units)
        from the next step on, as setting
        :attr:`~ase_reversible.md.base.ReversibleDynamics.dt` does -- a
        negated step runs back, a new size moves the anchor of reversal
        here (:class:`~ase_reversible.AnchorMovedWarning` if steps were
        taken).
        Refused, with nothing changed, where ``friction * |timestep|``
        is out of range (as in the constructor)."""
        timestep = check_timestep(timestep)
        checked_friction(self._friction, timestep)
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter('always', AnchorMovedWarning)
            self.dt = timestep
        for warning in caught:
            # At the caller's line, where ``dyn.dt = ...`` puts it.
            warnings.warn(warning.message, warning.category, stacklevel=2)

    def todict(self):
        """ASE's description plus the thermostat's settings and the
        quanta."""
        return {**super().todict(), 'temperature_K': self._temperature_K,
                'friction': self._friction, 'fixcm': self._fixcm,
                'seed': self._seed, **self.system.grid.todict(),
                'force_purity': self.force_purity.mode}


