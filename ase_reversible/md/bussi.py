"""ReversibleBussi: stochastic velocity rescaling that runs back exactly.

The thermostat of G. Bussi, D. Donadio and M. Parrinello ("Canonical
sampling through velocity rescaling", J. Chem. Phys. 126, 014101 (2007)),
with ASE's update (:class:`ase.md.bussi.Bussi`): every step multiplies all
momenta by one factor ``alpha``,

    alpha**2 = c + e (S + R**2) + 2 R sqrt(c e),
    c = exp(-h / taut),  e = (1 - c) kT / (2 K),

``K`` the kinetic energy, ``R`` a standard normal and ``S`` a chi-squared
variate with ``N_f - 1`` degrees of freedom, so that ``K`` follows the
canonical distribution's stochastic dynamics with time constant ``taut``
(``alpha`` the positive root, as ASE takes it).  Here the rescaling sits
between the two half drifts of a velocity Verlet step (kick, drift,
rescale, drift, kick: a palindrome, so the step run with ``-h`` undoes
it).  Kicks and drifts are the exact shears of
:mod:`.hamiltonian`; the rescaling is made exact in three parts:

* ``alpha`` is rounded to the ratio ``n / 2**20`` nearest to it (its
  relative error at most ``2**-21``, so that of ``alpha**2``, the factor
  on ``K``, at most ``2**-20 = 9.5e-7`` per step and as often up as
  down), computed from quantities with the same bits on every CPU: ``K``
  from the exact momentum counts in a fixed order of summation, ``c`` by
  the software exponential of :mod:`ase_reversible.core.portable`, ``R``
  and ``S`` from the counter-based generator of
  :mod:`ase_reversible.core.noise` keyed by the seed, the time step and
  the step's index, ``S`` as ``2 Gamma((N_f - 1) / 2)`` by
  Marsaglia and Tsang's method (``+ - * /``, ``sqrt`` and the portable
  logarithm on Python floats,
  :class:`~ase_reversible.core.noise.BussiDraws`: its cost does not grow
  with the number of atoms, as a sum of ``N_f - 1`` squared normals
  would);
* the momentum counts are multiplied by ``n / 2**20`` through an
  information buffer (:class:`~ase_reversible.core.scaling.ScalingBuffer`)
  that keeps the digits a ratio below one drops and supplies those a
  ratio above one needs; the
  product is within one count of ``n x / 2**20`` (``n / 2**20`` counts
  above one);
* the ratio ``n`` of each step is kept too (32 bits a step), since the
  way back cannot recompute it: ``alpha`` depends on the kinetic energy
  before the step, which the way back reaches only after undoing it.
"""

from __future__ import annotations

import functools
import math
from typing import NamedTuple

import numpy as np
from ase import units

from ..core.arguments import checked_positive
from ..core.compositions import composition_for
from ..core.noise import BussiDraws, step_key
from ..core import portable
from ..core.scaling import N_MAX, N_MIN, RATIO_BITS, ScalingBuffer
from ..errors import RetraceLimitError
from .buffered import BufferedDynamics, BufferedMomentumStep, resume_point
from .checks import (check_energy_watch, check_timestep,
                     refuse_plane_and_line_constraints, seed_from)
from .hamiltonian import largest_kick

DRIFT, KICK, RESCALE = 'drift', 'kick', 'rescale'

#: Velocity Verlet with the rescaling in the middle: a palindrome.
SCHEME = ((KICK, 0.5), (DRIFT, 0.5), (RESCALE, 1.0), (DRIFT, 0.5),
          (KICK, 0.5))

#: Default steps between checks of the energy balance.
ENERGY_CHECK_INTERVAL = 100

#: ``alpha`` is applied as ``n / 2**RATIO_BITS``.
_D = 1 << RATIO_BITS


class BussiSettings(NamedTuple):
    """What the rescaling reads of its dynamics when a step is prepared."""

    #: K.
    temperature_K: float
    #: The coupling's time constant, ASE time units.
    taut: float
    #: The key of the draws.
    seed: int


class RescalePlan(NamedTuple):
    """One rescaling at a coefficient ``ch``, as :meth:`Rescale.prepare`
    makes it (a coordinate index ``k`` runs over ``3 n_atoms``)."""

    #: ``ch > 0``.
    forward: bool
    #: The buffer of steps of size ``|ch|``.
    buffer: ScalingBuffer
    #: bool ``[3 n_atoms]`` of the coordinates moved, None for all.
    mask_k: object
    #: eV.
    kT: float
    #: ``exp(-|ch| / taut)``.
    c: float
    #: The Philox key of the step's draws.
    key: np.ndarray
    #: float ``[3 n_atoms]``: ``1 / m`` for the heat (1 / amu).
    inverse_mass_k: np.ndarray
    #: The coordinates FixCom holds, ``[(atom, component)]``, or None.
    held: object


# The software exp costs 4 us idle (19 us loaded); the way back asks at
# every step.
@functools.lru_cache(maxsize=16)
def decay(h, taut):
    """``c = exp(-|h| / taut)``, the same bits on every CPU."""
    return portable.exp(-abs(h) / taut)


def alpha_ratio(two_k, kT, c, r, s):
    """The numerator ``n`` of ``alpha`` as ``n / 2**20`` (module
    docstring), from ``2K = sum p**2 / m`` (eV), ``kT`` (eV), ``c`` and the
    draws ``R``, ``S``; IEEE operations in a fixed order only."""
    e = (1.0 - c) * kT / two_k
    alpha2 = c + e * (s + r * r) + 2.0 * r * math.sqrt(c * e)
    if not alpha2 < N_MAX * N_MAX / _D**2:  # also inf and NaN
        return N_MAX
    return round(math.sqrt(max(alpha2, 0.0)) * _D)


class Rescale(BufferedMomentumStep):
    """The rescaling of the momentum counts, exact (module docstring): a
    :class:`~.buffered.BufferedMomentumStep` whose ``settings()`` returns
    :class:`BussiSettings`, with a :class:`ScalingBuffer` per size of time
    step used since the anchor; ``heat`` is the kinetic energy the
    rescaling added since then (eV), ``heat_before_anchor`` what it added
    before (eV; kept when the anchor moves).
    """

    def __init__(self, system, settings, step_of):
        super().__init__(system, settings, step_of)
        self._draws = None
        self.heat_before_anchor = 0.0

    def forget(self):
        # ASE's transferred_energy counts from construction, through every
        # move of the anchor: one addition per move, none per step.
        self.heat_before_anchor += self.heat
        super().forget()

    def buffer_for(self, h):
        """The buffer of steps of size ``|h|`` (made if new)."""
        h = abs(h)
        buffer = self.buffers.get(h)
        if buffer is None:
            buffer = self.buffers[h] = ScalingBuffer(
                self.size, step_key(self.settings().seed, h))
        return buffer

    def arrays(self, h):
        """The buffer of steps of size ``|h|`` as a buffer file holds it,
        by array name."""
        b = self.buffer_for(h)
        base, words = b.used_rows()
        return {'buffer_state': b.state_k, 'buffer_top': b.top_k,
                'buffer_base': base, 'buffer_words': words,
                'buffer_ratios': b.ratios[:b.count]}

    def load(self, saved, h):
        """Take what :meth:`arrays` gave for ``h`` from ``saved`` (a
        buffer file's arrays by name)."""
        self.buffer_for(h).load(
            saved['buffer_state'], saved['buffer_top'], saved['buffer_base'],
            saved['buffer_words'], saved['buffer_ratios'])

    def prepare(self, ch):
        temperature_K, taut, seed = self.settings()
        s = self.system
        dof = ase_degrees_of_freedom(s.atoms)
        if self._draws is None or self._draws.dof != dof:
            self._draws = BussiDraws(dof)
        free_k = self.free_k()
        held = self._hold_one_per_component(free_k)
        return RescalePlan(ch > 0, self.buffer_for(ch),
                           None if free_k.all() else free_k,
                           units.kB * temperature_K, decay(ch, taut),
                           step_key(seed, ch), self.inverse_mass_k(), held)

    def apply(self, prepared):
        forward, buffer, mask_k, kT, c, key, inverse_mass_k, held = prepared
        x_k = self.counts_k()
        if forward:
            two_k = self.system.momentum_square()
            r, s = self._draws(key, self.step_of())
            n = _checked_ratio(two_k, kT, c, r, s) if two_k > 0 else None
            if n is None:
                raise ValueError(_ZERO_MOMENTA)
            new_k = buffer.scale(x_k, n, mask_k)
        else:
            try:
                new_k = buffer.unscale(x_k, mask_k)
            except IndexError:
                raise RetraceLimitError(
                    'ReversibleBussi can only retrace steps it has taken: '
                    'this one goes back past the anchor of reversal, where '
                    'no rescaling was applied that could be undone. The '
                    'step was not taken; run forward (positive dt) from '
                    'here.') from None
        self._commit(x_k, new_k, held, inverse_mass_k)

    def adjoint(self, cotangents, ch):
        """Pull ``a = dL/dp'`` back through ``p' = alpha(K(p)) p``:
        ``alpha a + (dalpha/dK) (a . p) p / m``, the rounding of ``alpha``
        and of the counts taken as the identity (as the kicks' rounding
        is).  ``alpha`` is the stored ratio of the step being undone,
        ``dalpha/dK`` that of the formula at ``p = p' / alpha`` with the
        step's draws."""
        cotangents.flush()
        temperature_K, taut, seed = self.settings()
        n = self.buffer_for(ch).last_ratio()
        if n is None:
            return  # undoing the step raises RetraceLimitError
        ratio = n / _D
        kT, c = units.kB * temperature_K, decay(ch, taut)
        s = self.system
        p_nc = s.p.floats / ratio
        two_k = s.momentum_square() / (ratio * ratio)
        r, chi = self._draws(step_key(seed, ch), self.step_of())
        e = (1.0 - c) * kT / two_k
        alpha = math.sqrt(c + e * (chi + r * r) + 2.0 * r * math.sqrt(c * e))
        # K = two_k / 2, dalpha/dK = d(alpha**2)/dK / (2 alpha).
        slope = -(2.0 * e / two_k) * (chi + r * r + r * math.sqrt(c / e)) \
            / (2.0 * alpha)
        a_nc = cotangents['momentum']
        free_nc = self._free() != 0
        projected = float(np.sum(np.where(free_nc, a_nc * p_nc, 0.0)))
        a_nc[...] = np.where(free_nc, ratio * a_nc, a_nc) \
            + (slope * projected) * p_nc / s.m_n1


def ase_degrees_of_freedom(atoms):
    """ASE's ``atoms.get_number_of_degrees_of_freedom()``: ``3N`` less what
    the constraints remove, written out where the method is missing (ASE
    3.23 has none; ReversibleBussi failed there)."""
    count = getattr(atoms, 'get_number_of_degrees_of_freedom', None)
    if count is not None:
        return count()
    return 3 * len(atoms) - sum(c.get_removed_dof(atoms)
                                for c in atoms.constraints)


_ZERO_MOMENTA = (
    'ReversibleBussi rescales the momenta, and they are all zero: there is '
    'nothing to rescale. Give the atoms momenta first, e.g. with '
    'ase.md.velocitydistribution.MaxwellBoltzmannDistribution(atoms, '
    'temperature_K=...). The step was not taken.')


def _checked_ratio(two_k, kT, c, r, s):
    n = alpha_ratio(two_k, kT, c, r, s)
    if not N_MIN <= n < N_MAX:
        temperature = two_k / kT  # K / (kT / 2) over all coordinates
        raise ValueError(
            f'ReversibleBussi would rescale the momenta by {n / _D:.3g} in '
            f'one step (the kinetic energy is {temperature:.3g} times kT/2 '
            f'summed over coordinates); factors in [2**-16, 2**7) are '
            'supported. Start from momenta near the target temperature '
            '(ase.md.velocitydistribution.MaxwellBoltzmannDistribution) '
            'or use a longer taut. The step was not taken; the state is '
            'valid and reverse() leads back exactly.')
    return n


class ReversibleBussi(BufferedDynamics):
    """Stochastic velocity rescaling (NVT) in fixed point that runs back
    exactly.

    A drop-in for :class:`ase.md.bussi.Bussi`: the same thermostat (all
    momenta multiplied by one random factor a step, so that the kinetic
    energy samples the canonical distribution), with the rescaling between
    the half drifts of a velocity Verlet step.  After ``run(n)``,
    :meth:`reverse` and ``run(n)`` positions, momenta and the buffer are
    bitwise those right after the constructor (module docstring); the way
    back goes no further (:class:`~ase_reversible.RetraceLimitError`).

    Parameters
    ----------
    atoms : ase.Atoms
        With a calculator attached and momenta not all zero.
    timestep : float
        ASE time units (``5 * ase.units.fs``).
    temperature_K : float
        Target temperature, K.
    taut : float
        Time constant of the coupling, ASE time units (``100 *
        ase.units.fs``); positive.
    rng : numpy.random.Generator or RandomState, optional
        As ASE's (also its fifth positional argument): used once, to draw
        the seed (a single draw from it), so the same seeded generator
        gives the same run; the seed drawn is recorded and resumes the
        run as one passed as ``seed`` would.  Not together with ``seed``.
    seed : int, optional
        Key of the random draws, stored as ``seed``
        (:attr:`~ase_reversible.md.buffered.BufferedDynamics.seed`).
        Default: the seed in the atoms' restart record if it was written
        at this time step, else drawn from the operating system.
    buffer : str or path, optional
        A file :meth:`write_buffer` wrote together with the frame these
        atoms come from: the run then goes on bit for bit as the one that
        wrote it, and runs back past this point.  Without it, a frame goes
        on with the same draws but a fresh buffer, whose digits enter the
        rescaling's rounding: the same statistics, not the same bits, and
        no way back past it.
    trajectory, logfile, loginterval
        As for :class:`ase.md.bussi.Bussi`.
    position_quantum, momentum_quantum, force_purity, force_noise
        As for :class:`~ase_reversible.ReversibleVerlet`.
    energy_check : int
        As for :class:`~ase_reversible.ReversibleVerlet`, for the total
        energy minus the heat the thermostat added since the anchor
        (``heat``,
        :attr:`~ase_reversible.md.buffered.BufferedDynamics.heat`).
    energy_tolerance : float, optional
        eV; default as for :class:`~ase_reversible.ReversibleVerlet`.

    The degrees of freedom are ASE's count,
    ``atoms.get_number_of_degrees_of_freedom()``: ``3N`` less those
    constraints remove (3 for ``FixCom``, which holds the total momentum
    at exactly zero here).  The draws come from a counter-based generator
    that the way back can start again, keyed by the seed (``rng`` only
    draws it).  ASE's attributes ``temp``, ``ndof``,
    ``target_kinetic_energy`` and ``transferred_energy`` are there, in
    ASE's units.

    Raises
    ------
    TypeError
        ``fixcm``, an ``rng`` that is not a numpy generator, or a setting
        that is not a number.
    ValueError
        ``taut`` or ``temperature_K`` not positive, ``seed`` and ``rng``
        both given, momenta all zero.
    UnsupportedConstraintError
        A constraint other than FixAtoms, FixCartesian and FixCom.
    """

    record_sections = ('bussi',)
    rigid_bodies = True
    buffer_mark = 'buffer_ratios'

    def __init__(self, atoms, timestep, temperature_K, taut, rng=None, *,
                 seed=None, buffer=None, trajectory=None, logfile=None,
                 loginterval=1, position_quantum=None, momentum_quantum=None,
                 force_purity='auto', force_noise=None,
                 energy_check=ENERGY_CHECK_INTERVAL, energy_tolerance=None,
                 **kwargs):
        if 'fixcm' in kwargs:
            raise TypeError(
                'ReversibleBussi has no fixcm, as ASE\'s Bussi has none: one '
                'factor scales every momentum, so a zero total momentum '
                'stays zero but for rounding. To hold it at exactly zero, '
                'add the constraint ase.constraints.FixCom.')
        timestep = check_timestep(timestep)
        self._temperature_K = checked_positive(temperature_K,
                                               'temperature_K', 'K')
        self._taut = checked_positive(taut, 'taut',
                                      'ASE time units, e.g. 100 * units.fs')
        energy_check, energy_tolerance = check_energy_watch(
            energy_check, energy_tolerance)
        seed = seed_from(seed, rng, 'ReversibleBussi')
        refuse_plane_and_line_constraints(atoms, 'ReversibleBussi',
                                          'the rescaling')
        momenta = atoms.get_momenta()
        if not np.any(momenta):
            raise ValueError(_ZERO_MOMENTA.replace(' The step was not '
                                                   'taken.', ''))
        system, record = self._hamiltonian(
            atoms, largest_kick(SCHEME, composition_for(2, None), timestep,
                                KICK),
            position_quantum, momentum_quantum,
            force_purity, force_noise)
        self._seed, step = resume_point(
            record.get('bussi') if record else None, timestep, seed)
        rescale = Rescale(system, self._settings, self._step_of)
        substep = {KICK: system.kick, DRIFT: system.drift, RESCALE: rescale}
        engine = self._buffered_engine(system, SCHEME, substep, timestep,
                                       energy_check, energy_tolerance)
        self.rescale_step = self.buffered_step = rescale
        self._resume(engine, step, buffer, {},
                     lambda saved: rescale.load(saved, timestep))
        self._open(system, engine, record, (force_purity, force_noise),
                   timestep, trajectory=trajectory, logfile=logfile,
                   loginterval=loginterval, **kwargs)

    # -- what the rescaling reads ------------------------------------------

    def _settings(self):
        return BussiSettings(self._temperature_K, self._taut, self._seed)

    def _take_changes(self, changes):
        refuse_plane_and_line_constraints(self.atoms, 'ReversibleBussi',
                                          'the rescaling')
        return super()._take_changes(changes)

    def _record_sections(self):
        return {'bussi': {'seed': self._seed,
                          'step': self.engine.step_index,
                          'timestep': abs(self.engine.dt)}}

    def write_buffer(self, path):
        """Write what reversal through this point needs to ``path`` (NumPy
        ``.npz``): the buffer with its ratios, the anchor of reversal and
        the step, tied to the present state by a digest.

        A frame written now and this file make a restart that continues
        bit for bit and runs back past the restart point to the anchor:
        ``ReversibleBussi(frame, dt, T, taut, buffer=path)``.
        """
        self._save_buffer(path, self.rescale_step.arrays(self.engine.dt))

    # -- the thermostat's settings -----------------------------------------

    @property
    def temperature_K(self) -> float:
        """Target temperature, K (change it with :meth:`set_temperature`)."""
        return self._temperature_K

    @property
    def taut(self) -> float:
        """Time constant of the coupling, ASE time units."""
        return self._taut

    @property
    def temp(self) -> float:
        """Target ``kB T``, eV: ASE's ``Bussi.temp``."""
        return self._temperature_K * units.kB

    @property
    def ndof(self) -> int:
        """The degrees of freedom thermostatted, ASE's ``Bussi.ndof``:
        ``atoms.get_number_of_degrees_of_freedom()`` (3N less those the
        constraints remove, read as each step is prepared)."""
        return ase_degrees_of_freedom(self.atoms)

    @property
    def target_kinetic_energy(self) -> float:
        """``temp * ndof / 2``, eV: ASE's ``Bussi.target_kinetic_energy``."""
        return 0.5 * self.temp * self.ndof

    @property
    def transferred_energy(self) -> float:
        """Kinetic energy the rescaling has put into the atoms since
        construction, eV: ASE's ``Bussi.transferred_energy``, so that
        ``atoms.get_total_energy() - transferred_energy`` is conserved but
        for the time-step error.  Net: a step run back takes its share out
        again.  Unlike
        :attr:`~ase_reversible.md.buffered.BufferedDynamics.heat`, it does
        not restart where the anchor of reversal moves."""
        step = self.rescale_step
        return step.heat_before_anchor + step.heat

    def set_temperature(self, temperature_K):
        """Use ``temperature_K`` (K) from the next step on; the anchor
        moves here (:class:`~ase_reversible.AnchorMovedWarning` if steps
        were taken)."""
        value = checked_positive(temperature_K, 'temperature_K', 'K')
        self._change_setting('temperature', lambda: setattr(
            self, '_temperature_K', value))

    def set_taut(self, taut):
        """Use ``taut`` (ASE time units) from the next step on; the anchor
        moves here, as for :meth:`set_temperature`."""
        value = checked_positive(taut, 'taut', 'ASE time units')
        self._change_setting('taut', lambda: setattr(self, '_taut', value))

    def todict(self):
        """ASE's description plus the thermostat's settings and the
        quanta."""
        return {**super().todict(), 'temperature_K': self._temperature_K,
                'taut': self._taut, 'seed': self._seed,
                **self.system.grid.todict(),
                'force_purity': self.force_purity.mode}
