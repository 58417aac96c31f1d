"""ReversibleLangevin against ASE's Langevin, ReversibleBussi against ASE's
Bussi: sampling, reversal, buffer, cost.

A section of ``run_all.py``::

    python benchmarks/run_all.py --only thermostat           # ~9 minutes
    python benchmarks/run_all.py --quick --only thermostat   # ~15 s

Systems: periodic fcc argon (asap3 LennardJones, 80 K, 10 fs) and copper
(asap3 EMT, 600 K, 5 fs), 256 atoms each, friction 0.01 / fs, momenta
drawn at the temperature and the centre-of-mass momentum removed
(``Stationary``).

1. Sampling.  ReversibleLangevin (``fixcm=True``: its noise has exactly
   zero net momentum) and ASE's ``Langevin`` run from the same atoms.  ASE
   3.29 deprecates ``Langevin(fixcm=True)``: it scales the noise by
   ``sqrt(N / (N - 1))`` so that ``get_temperature()`` (kinetic energy
   over 3N degrees of freedom) averages T, which heats the 3N - 3 internal
   ones to ``T N / (N - 1)``.  Like with like is ASE's replacement,
   ``fixcm=False`` with the ``FixCom`` constraint: both thermostats then
   keep the centre of mass at rest and should give each of the ``3N - 3``
   internal degrees of freedom ``kT / 2``.  So the kinetic energy measured
   is the internal one, ``K - P**2 / 2M`` (P the total momentum, M the
   total mass), for both, and its analytic distribution is Gamma with shape
   ``(3N - 3) / 2`` and scale ``kT``.  After ``equilibration`` steps every
   step is sampled (kinetic and potential energy).  Standard errors of
   means come from block averages (``BLOCKS`` blocks); the correlation time
   is the integrated autocorrelation time ``g = 1 + 2 sum rho(t)`` summed
   up to the first lag ``m >= 5 g(m)`` (Sokal's window), and the
   Kolmogorov-Smirnov test takes every ``ceil(2 g)``-th sample.
2. Exact reversal: ReversibleLangevin's sampling run *is* the first half
   of a round trip: after it, ``reverse()`` and as many steps back (no
   observer), then positions, momenta and the integer state are compared
   with those right after the constructor with ``np.array_equal``, and
   the information buffers must be empty.
3. Buffer size: the bits the buffers hold (``buffer_bits``) and their
   memory (``nbytes``, and the words allocated) at checkpoints of the
   forward half, against the least any exact scheme keeps, ``-log2(c)``
   bits per coordinate and step for the ratio ``c = n / 2**16`` applied,
   and against a stored trajectory (positions and momenta, float64, every
   step).  10**6 steps are extrapolated linearly from the last two
   checkpoints.
4. Cost per step: ReversibleLangevin, ASE Langevin (``FixCom``, as in 1.),
   ASE VelocityVerlet and ReversibleVerlet on copies of the same atoms,
   each with its own calculator, timed in interleaved rounds with the
   helpers of ``step_cost.py``.
5. Bussi.  ReversibleBussi and ASE's ``Bussi`` (``taut`` = 100 fs, both
   with ``FixCom``, so both count ``3N - 3`` degrees of freedom and target
   Gamma((3N - 3) / 2, kT)) on liquid argon (256 atoms, asap3
   LennardJones, the fcc lattice expanded by 1.10 to 1.37 g/cm3, momenta
   drawn at 600 K, thermostat at 90 K, 10 fs: it melts in the
   equilibration; rms displacement 3.8 A in 10 ps, measured) and on the
   copper crystal above, where a single Nosé thermostat fails (nose.py).
   After ``BUSSI.equilibration`` steps every step is sampled as in 1.
   ReversibleBussi's sampling run is again the first half of a round trip
   (2.); its buffer (``buffer_bits``: the coordinates' part random-walks
   around zero, the stored ratios add 32 bits a step) is read at
   checkpoints.  Cost per step: ReversibleBussi, ASE Bussi,
   ReversibleLangevin and ASE VelocityVerlet, interleaved as in 4.
"""

from __future__ import annotations

import common  # noqa: F401  (first: pins BLAS threads before numpy)

import math
import os
import statistics
import sys
import time
import warnings
from dataclasses import asdict, dataclass
from typing import Callable

import numpy as np
from ase import units
from ase.constraints import FixCom
from ase.md.bussi import Bussi
from ase.md.langevin import Langevin
from ase.md.velocitydistribution import Stationary
from ase.md.verlet import VelocityVerlet
from scipy import stats
from step_cost import (Contestant, Settings, choose_steps, time_cached_queries,
                       time_interleaved)
from systems import CALCULATORS

from ase_reversible import (ReversibleBussi, ReversibleLangevin,
                            ReversibleVerlet)
from ase_reversible.app.systems import argon_bulk, copper_bulk
from ase_reversible.core.infobuffer import DIGIT_BITS, friction_ratio

#: Friction of every run, 1 / fs.
FRICTION_PER_FS = 0.01
#: Seed of ReversibleLangevin's noise and of ASE Langevin's generator.
SEED = 7
#: Blocks of the block averages.
BLOCKS = 20
#: Bins of the stored kinetic-energy histograms.
HISTOGRAM_BINS = 40
#: Sokal's window: sum the autocorrelation up to the first m >= C g(m).
WINDOW_C = 5.0
#: Steps between readings of sum F**2 / m (for the mean squared frequency).
FORCE_EVERY = 10
#: The goals judged on the page.
TEMPERATURE_GOAL_PERCENT = 1.0
BITS_GOAL_RATIO = 1.1
#: 8 bytes each for a position and a momentum per coordinate and step.
TRAJECTORY_BYTES_PER_COORDINATE = 16


@dataclass(frozen=True)
class System:
    label: str
    calculator: str  # key of systems.CALCULATORS
    build: Callable  # (repeat, temperature_K) -> atoms
    repeat: tuple
    temperature_K: float
    timestep_fs: float
    force_noise: float = None  # eV/Å, for ReversibleBussi

    def atoms(self, repeat=None):
        atoms = self.build(repeat or self.repeat, self.temperature_K)
        Stationary(atoms)  # both thermostats keep the centre of mass at rest
        atoms.calc = CALCULATORS[self.calculator]()
        return atoms


SYSTEMS = (
    System('Ar fcc', 'asap3 LJ', argon_bulk, (4, 4, 4), 80.0, 10.0),
    System('Cu fcc', 'asap3 EMT', copper_bulk, (4, 4, 4), 600.0, 5.0),
)


@dataclass(frozen=True)
class Lengths:
    equilibration: int
    round_trip: int  # forward steps, equilibration included
    checkpoints: tuple  # forward steps at which the buffer is measured


FULL = Lengths(equilibration=2000, round_trip=100_000,
               checkpoints=(1000, 10_000, 100_000))
QUICK = Lengths(equilibration=200, round_trip=1000, checkpoints=(100, 1000))
#: Steps the memory is extrapolated to.
EXTRAPOLATE_TO = 1_000_000

SPEED_FULL = Settings(rounds=9, block_seconds=0.5, min_steps=2,
                      max_steps=2000, warmup_steps=5)
SPEED_QUICK = Settings(rounds=3, block_seconds=0.05, min_steps=2,
                       max_steps=200, warmup_steps=2)
#: (system, repeat) of the cost cases: Cu 500 and 4000, Ar 500 atoms.
SPEED_CASES = ((SYSTEMS[1], (5, 5, 5)), (SYSTEMS[1], (10, 10, 10)),
               (SYSTEMS[0], (5, 5, 5)))
QUICK_SPEED_CASES = SPEED_CASES[::2]
SPEED_CONTESTANTS = ('reversible_langevin', 'ase_langevin', 'velocity_verlet',
                     'reversible_verlet')


# -- the thermostats --------------------------------------------------------

def reversible_langevin(atoms, system):
    return ReversibleLangevin(atoms, system.timestep_fs * units.fs,
                              system.temperature_K,
                              FRICTION_PER_FS / units.fs, fixcm=True,
                              seed=SEED)


def ase_langevin(atoms, system):
    """ASE's Langevin with the centre of mass held by FixCom (see top)."""
    atoms.set_constraint(FixCom())
    return Langevin(atoms, system.timestep_fs * units.fs,
                    temperature_K=system.temperature_K,
                    friction=FRICTION_PER_FS / units.fs, fixcm=False,
                    rng=np.random.default_rng(SEED))


#: Time constant of both Bussi thermostats, fs.
TAUT_FS = 100.0


def reversible_bussi(atoms, system):
    atoms.set_constraint(FixCom())
    return ReversibleBussi(atoms, system.timestep_fs * units.fs,
                           system.temperature_K, TAUT_FS * units.fs,
                           seed=SEED, force_noise=system.force_noise)


def ase_bussi(atoms, system):
    atoms.set_constraint(FixCom())
    return Bussi(atoms, system.timestep_fs * units.fs, system.temperature_K,
                 TAUT_FS * units.fs, rng=np.random.default_rng(SEED))


INTEGRATORS = {
    'reversible_bussi': reversible_bussi,
    'ase_bussi': ase_bussi,
    'reversible_langevin': reversible_langevin,
    'ase_langevin': ase_langevin,
    'velocity_verlet': lambda atoms, system: VelocityVerlet(
        atoms, system.timestep_fs * units.fs),
    'reversible_verlet': lambda atoms, system: ReversibleVerlet(
        atoms, system.timestep_fs * units.fs),
}


# -- sampling ---------------------------------------------------------------

class Sampler:
    """Observer: the internal kinetic and the potential energy after every
    step, indexed by ``dyn.nsteps`` (0: before the first step)."""

    def __init__(self, dyn, steps):
        self.dyn, self.atoms = dyn, dyn.atoms
        self.kinetic = np.full(steps + 1, np.nan)
        self.potential = np.full(steps + 1, np.nan)
        self.com_kinetic = np.full(steps + 1, np.nan)
        self.force_square = np.full(steps + 1, np.nan)
        self.total_mass = float(self.atoms.get_masses().sum())

    def __call__(self):
        i = self.dyn.nsteps
        p_nc = self.atoms.get_momenta()
        p_c = p_nc.sum(axis=0)
        k = 0.5 * float((p_nc**2 / self.atoms.get_masses()[:, None]).sum())
        self.com_kinetic[i] = 0.5 * float(p_c @ p_c) / self.total_mass
        self.kinetic[i] = k - self.com_kinetic[i]
        self.potential[i] = self.atoms.get_potential_energy()
        if i % FORCE_EVERY == 0:
            f_nc = self.atoms.get_forces()
            self.force_square[i] = float(
                (f_nc**2 / self.atoms.get_masses()[:, None]).sum())


def integrated_time(x):
    """Integrated autocorrelation time ``g = 1 + 2 sum_t rho(t)`` (in
    samples), summed up to the first lag ``m >= WINDOW_C g(m)``."""
    x = np.asarray(x, float) - np.mean(x)
    n = len(x)
    f = np.fft.rfft(x, 2 * n)
    acf = np.fft.irfft(f * np.conj(f))[:n]
    acf /= acf[0]
    g = 2.0 * np.cumsum(acf) - 1.0
    window = np.arange(n) >= WINDOW_C * g
    m = int(np.argmax(window)) if window.any() else n - 1
    return float(g[m])


def block_mean(x, blocks=BLOCKS):
    """Mean and its standard error from ``blocks`` block averages."""
    x = np.asarray(x, float)
    length = len(x) // blocks
    means = x[:length * blocks].reshape(blocks, length).mean(axis=1)
    return {'mean': float(x.mean()),
            'standard_error': float(means.std(ddof=1) / math.sqrt(blocks)),
            'blocks': blocks, 'block_length': length}


def lag1(x):
    x = np.asarray(x, float) - np.mean(x)
    return float((x[1:] @ x[:-1]) / (x @ x))


def statistics_of(sampler, first, dof, kT, edges, timestep):
    """The sampling results of the steps from ``first`` on."""
    kinetic = sampler.kinetic[first:]
    potential = sampler.potential[first:]
    assert np.all(np.isfinite(kinetic)) and np.all(np.isfinite(potential))
    g = integrated_time(kinetic)
    stride = math.ceil(2 * g)
    thinned = kinetic[::stride]
    ks = stats.kstest(thinned, 'gamma', args=(dof / 2, 0.0, kT))
    # The shape alone: the scale from the measured mean kinetic energy.
    ks_shape = stats.kstest(thinned, 'gamma',
                            args=(dof / 2, 0.0, 2 * kinetic.mean() / dof))
    temperature = block_mean(2 * kinetic / (dof * units.kB))
    counts, _ = np.histogram(kinetic, edges)
    # <omega**2> over the internal modes: <F_i**2> = kT <d2U/dx_i**2>, so
    # sum_i <F_i**2 / m_i> / (kT dof) is the trace of the mass-weighted
    # Hessian over the modes.  For a harmonic system BAOAB's momenta at
    # the full step have <p**2> = m kT (1 - h**2 omega**2 / 4).
    force_square = sampler.force_square[first:]
    omega2 = float(np.nanmean(force_square) / (kT * dof))
    return {
        'mean_omega_squared_per_fs2': omega2 * units.fs**2,
        'baoab_harmonic_kinetic_bias_percent':
            -100 * timestep**2 * omega2 / 4,
        'samples': len(kinetic),
        'temperature_K': temperature,
        'potential_energy': {**block_mean(potential),
                             'correlation_time_steps':
                                 integrated_time(potential)},
        'kinetic_correlation_time_steps': g,
        'ks': {'stride': stride, 'samples': len(thinned),
               'lag1_of_thinned': lag1(thinned),
               'statistic': float(ks.statistic),
               'p_value': float(ks.pvalue),
               'shape_statistic': float(ks_shape.statistic),
               'shape_p_value': float(ks_shape.pvalue)},
        'max_com_kinetic_over_kT': float(np.max(sampler.com_kinetic[first:])
                                         / kT),
        'histogram_counts': counts.tolist(),
    }


# -- ReversibleLangevin: sampling, round trip, buffer ------------------------

def buffer_sizes(dyn, steps, coordinates):
    buffers = dyn.friction_step.buffers.values()
    bits = dyn.buffer_bits
    nbytes = sum(b.nbytes for b in buffers)
    allocated = sum(b.state_k.nbytes + b.top_k.nbytes + b.words_jk.nbytes
                    for b in buffers)
    return {'steps': steps, 'bits': bits,
            'bits_per_step_per_coordinate': bits / (steps * coordinates),
            'nbytes': nbytes, 'allocated_bytes': allocated,
            'trajectory_bytes': TRAJECTORY_BYTES_PER_COORDINATE
            * coordinates * steps}


def run_reversible(system, lengths):
    """ReversibleLangevin's sampling run, then the same steps back."""
    atoms = system.atoms()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter('always')
        dyn = reversible_langevin(atoms, system)
        start_state = dyn.state
        x0_nc, p0_nc = atoms.get_positions(), atoms.get_momenta()
        coordinates = 3 * len(atoms)
        sampler = Sampler(dyn, lengths.round_trip)
        dyn.attach(sampler, interval=1)
        checkpoints, done = [], 0
        tic = time.perf_counter()
        for stop in sorted(set(lengths.checkpoints)
                           | {lengths.round_trip}):
            dyn.run(stop - done)
            done = stop
            if stop in lengths.checkpoints:
                checkpoints.append(buffer_sizes(dyn, stop, coordinates))
        forward_seconds = time.perf_counter() - tic
        moved = not np.array_equal(atoms.get_positions(), x0_nc)
        dyn.observers.clear()  # the way back is a plain run
        dyn.reverse()
        tic = time.perf_counter()
        dyn.run(lengths.round_trip)
        back_seconds = time.perf_counter() - tic
    end_state = dyn.state
    buffers = list(dyn.friction_step.buffers.values())
    round_trip = {
        'steps_each_way': lengths.round_trip,
        'moved': moved,
        'positions_equal': bool(np.array_equal(atoms.get_positions(),
                                               x0_nc)),
        'momenta_equal': bool(np.array_equal(atoms.get_momenta(), p0_nc)),
        'state_equal': bool(np.array_equal(end_state.ix_nc,
                                           start_state.ix_nc)
                            and np.array_equal(end_state.ip_nc,
                                               start_state.ip_nc)),
        'buffer_empty': bool(buffers and all(b.is_empty() for b in buffers)),
        'buffer_bits_after': dyn.buffer_bits,
        'heat_after_eV': dyn.heat,
        'forward_seconds': forward_seconds,
        'back_seconds': back_seconds,
        'warnings': sorted({f'{w.category.__name__}: {w.message}'
                            for w in caught}),
    }
    n = friction_ratio(math.exp(-FRICTION_PER_FS * system.timestep_fs))
    buffer = {
        'ratio_numerator': n,
        'ratio': n / 2**DIGIT_BITS,
        'minimum_bits_per_step_per_coordinate':
            -math.log2(n / 2**DIGIT_BITS),
        'effective_friction_per_fs': dyn.effective_friction * units.fs,
        'checkpoints': checkpoints,
    }
    return sampler, round_trip, buffer


def run_ase(system, steps):
    atoms = system.atoms()
    dyn = ase_langevin(atoms, system)
    sampler = Sampler(dyn, steps)
    dyn.attach(sampler, interval=1)
    tic = time.perf_counter()
    dyn.run(steps)
    return sampler, time.perf_counter() - tic


def extrapolated(checkpoints, steps=EXTRAPOLATE_TO):
    """Linear through the last two checkpoints, at ``steps`` (not the
    allocated bytes: the stacks grow by doubling)."""
    a, b = checkpoints[-2], checkpoints[-1]
    out = {'steps': steps, 'extrapolated': True}
    for key in ('bits', 'nbytes', 'trajectory_bytes'):
        slope = (b[key] - a[key]) / (b['steps'] - a['steps'])
        out[key] = b[key] + slope * (steps - b['steps'])
    return out


def histogram_edges(dof, kT):
    """Bins of the kinetic-energy histograms: equal widths over the central
    99.9% of Gamma(dof / 2, kT)."""
    ends = stats.gamma.ppf([0.0005, 0.9995], dof / 2, scale=kT)
    return np.linspace(ends[0], ends[1], HISTOGRAM_BINS + 1)


def sampling_system(system, lengths):
    n_atoms = 4 * int(np.prod(system.repeat))
    dof = 3 * n_atoms - 3
    kT = units.kB * system.temperature_K
    edges = histogram_edges(dof, kT)
    ours, round_trip, buffer = run_reversible(system, lengths)
    theirs, ase_seconds = run_ase(system, lengths.round_trip)
    first = lengths.equilibration + 1
    h = system.timestep_fs * units.fs
    sampled = {'reversible_langevin': statistics_of(ours, first, dof, kT,
                                                    edges, h),
               'ase_langevin': statistics_of(theirs, first, dof, kT, edges,
                                             h)}
    sampled['ase_langevin']['seconds'] = ase_seconds
    a = sampled['reversible_langevin']['potential_energy']
    b = sampled['ase_langevin']['potential_energy']
    se = math.hypot(a['standard_error'], b['standard_error'])
    buffer['extrapolated'] = extrapolated(buffer['checkpoints'])
    result = {
        'system': system.label, 'calculator': system.calculator,
        'n_atoms': n_atoms, 'dof': dof,
        'temperature_K': system.temperature_K,
        'timestep_fs': system.timestep_fs, 'kT_eV': kT,
        'equilibration_steps': lengths.equilibration,
        'histogram_edges_eV': edges.tolist(),
        'sampling': sampled,
        'potential_difference_eV': a['mean'] - b['mean'],
        'potential_difference_standard_error_eV': se,
        'round_trip': round_trip,
        'buffer': buffer,
    }
    t_ours = sampled['reversible_langevin']['temperature_K']['mean']
    t_ase = sampled['ase_langevin']['temperature_K']['mean']
    print(f'  {system.label:7s} N={n_atoms}  T_kin {t_ours:.2f} / '
          f'{t_ase:.2f} K  dE_pot {a["mean"] - b["mean"]:+.4f} eV '
          f'({(a["mean"] - b["mean"]) / se:+.1f} SE)  exact '
          f'{round_trip["state_equal"]}  '
          f'{round_trip["forward_seconds"] + round_trip["back_seconds"]:.0f}'
          ' s', flush=True)
    return result


# -- Bussi --------------------------------------------------------------------

def liquid_argon(repeat, temperature_K):
    """fcc argon expanded by 1.10 (1.37 g/cm3), momenta drawn at
    ``temperature_K``: it melts as a thermostat cools it."""
    atoms = argon_bulk(repeat, temperature_K)
    atoms.set_cell(atoms.cell * 1.10, scale_atoms=True)
    return atoms


def drawn_at(build, temperature_K):
    return lambda repeat, _: build(repeat, temperature_K)


#: The Bussi systems: liquid argon (asap3 LennardJones needs a force-noise
#: bound above the default at this density: 4e-15 eV/Å was seen against a
#: bound of 3.6e-15) and the copper crystal of SYSTEMS.
BUSSI_SYSTEMS = (
    System('Ar liquid', 'asap3 LJ', drawn_at(liquid_argon, 600.0),
           (4, 4, 4), 90.0, 10.0, force_noise=1e-13),
    SYSTEMS[1],
)


@dataclass(frozen=True)
class BussiLengths:
    equilibration: int
    steps: int  # forward steps, equilibration included
    checkpoints: tuple


BUSSI_FULL = BussiLengths(equilibration=1000, steps=21_000,
                          checkpoints=(1000, 5000, 21_000))
BUSSI_QUICK = BussiLengths(equilibration=200, steps=1000,
                           checkpoints=(200, 1000))
BUSSI_SPEED_CASES = ((SYSTEMS[1], (5, 5, 5)), (SYSTEMS[1], (10, 10, 10)))
BUSSI_SPEED_CONTESTANTS = ('reversible_bussi', 'ase_bussi',
                           'reversible_langevin', 'velocity_verlet')


def bussi_buffer(dyn, steps, coordinates):
    (b,) = dyn.rescale_step.buffers.values()
    ratio_bits = 32.0 * b.count
    return {'steps': steps, 'bits': dyn.buffer_bits,
            'ratio_bits': ratio_bits,
            'coordinate_bits': dyn.buffer_bits - ratio_bits,
            'coordinate_bits_per_coordinate':
                (dyn.buffer_bits - ratio_bits) / coordinates,
            'lowest_stack_pointer': int(b.top_k.min()),
            'highest_stack_pointer': int(b.top_k.max()),
            'nbytes': b.nbytes}


def bussi_system(system, lengths):
    """Both Bussi thermostats on ``system``; ours then runs back."""
    atoms = system.atoms()
    n_atoms, dof = len(atoms), 3 * len(atoms) - 3
    kT = units.kB * system.temperature_K
    edges = histogram_edges(dof, kT)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter('always')
        dyn = reversible_bussi(atoms, system)
        start = dyn.state
        ours = Sampler(dyn, lengths.steps)
        dyn.attach(ours, interval=1)
        checkpoints, done = [], 0
        tic = time.perf_counter()
        for stop in sorted(set(lengths.checkpoints) | {lengths.steps}):
            dyn.run(stop - done)
            done = stop
            if stop in lengths.checkpoints:
                checkpoints.append(bussi_buffer(dyn, stop, 3 * n_atoms))
        forward_seconds = time.perf_counter() - tic
        moved = not np.array_equal(dyn.state.ix_nc, start.ix_nc)
        dyn.observers.clear()
        dyn.reverse()
        tic = time.perf_counter()
        dyn.run(lengths.steps)
        back_seconds = time.perf_counter() - tic
    end = dyn.state
    (buffer,) = dyn.rescale_step.buffers.values()
    round_trip = {
        'steps_each_way': lengths.steps, 'moved': moved,
        'state_equal': bool(np.array_equal(end.ix_nc, start.ix_nc)
                            and np.array_equal(end.ip_nc, start.ip_nc)),
        'buffer_empty': buffer.is_empty(),
        'forward_seconds': forward_seconds, 'back_seconds': back_seconds,
        'warnings': sorted({f'{w.category.__name__}: {w.message}'
                            for w in caught})}
    atoms = system.atoms()
    theirs_dyn = ase_bussi(atoms, system)
    theirs = Sampler(theirs_dyn, lengths.steps)
    theirs_dyn.attach(theirs, interval=1)
    tic = time.perf_counter()
    theirs_dyn.run(lengths.steps)
    ase_seconds = time.perf_counter() - tic
    first = lengths.equilibration + 1
    h = system.timestep_fs * units.fs
    sampled = {'reversible_bussi': statistics_of(ours, first, dof, kT,
                                                 edges, h),
               'ase_bussi': statistics_of(theirs, first, dof, kT, edges, h)}
    sampled['ase_bussi']['seconds'] = ase_seconds
    a = sampled['reversible_bussi']['potential_energy']
    b = sampled['ase_bussi']['potential_energy']
    se = math.hypot(a['standard_error'], b['standard_error'])
    t = {k: sampled[k]['temperature_K'] for k in sampled}
    print(f"  Bussi {system.label:9s} N={n_atoms}  T_kin "
          f"{t['reversible_bussi']['mean']:.2f} / "
          f"{t['ase_bussi']['mean']:.2f} K  KS p "
          f"{sampled['reversible_bussi']['ks']['p_value']:.2g} / "
          f"{sampled['ase_bussi']['ks']['p_value']:.2g}  exact "
          f"{round_trip['state_equal']}", flush=True)
    return {'system': system.label, 'calculator': system.calculator,
            'n_atoms': n_atoms, 'dof': dof,
            'temperature_K': system.temperature_K,
            'timestep_fs': system.timestep_fs, 'taut_fs': TAUT_FS,
            'kT_eV': kT, 'equilibration_steps': lengths.equilibration,
            'histogram_edges_eV': edges.tolist(), 'sampling': sampled,
            'potential_difference_eV': a['mean'] - b['mean'],
            'potential_difference_standard_error_eV': se,
            'round_trip': round_trip, 'buffer_checkpoints': checkpoints}


def run_bussi(quick):
    lengths = BUSSI_QUICK if quick else BUSSI_FULL
    speed = SPEED_QUICK if quick else SPEED_FULL
    systems_ = [bussi_system(s, lengths) for s in BUSSI_SYSTEMS]
    cases = BUSSI_SPEED_CASES[:1] if quick else BUSSI_SPEED_CASES
    costs = [speed_case(s, r, speed, names=BUSSI_SPEED_CONTESTANTS,
                        reference='ase_bussi') for s, r in cases]
    return {'lengths': asdict(lengths), 'taut_fs': TAUT_FS,
            'systems': systems_, 'speed': costs}


# -- cost per step ----------------------------------------------------------

def speed_case(system, repeat, settings, names=SPEED_CONTESTANTS,
               integrators=INTEGRATORS, reference='ase_langevin'):
    """Interleaved per-step times of the integrators ``names`` (keys of
    ``integrators``, each ``(atoms, system) -> dynamics``), blocks sized on
    ``reference``; ``names`` must include 'velocity_verlet'."""
    template = system.atoms(repeat)
    contestants = []
    for name in names:
        atoms = template.copy()
        atoms.calc = CALCULATORS[system.calculator]()
        contestants.append(Contestant(name, integrators[name](atoms, system)))
    for c in contestants:
        c.runner.run(settings.warmup_steps)
    by_name = {c.name: c for c in contestants}
    steps = choose_steps(by_name[reference], settings)
    wall, cpu = time_interleaved(contestants, steps, settings.rounds)
    median = {k: statistics.median(v) for k, v in wall.items()}
    # ASE's integrators ask for the forces again at unchanged positions.
    forces_again, _ = time_cached_queries(
        by_name['velocity_verlet'].runner.atoms, min(steps, 20))
    result = {
        'system': system.label, 'calculator': system.calculator,
        'n_atoms': len(template), 'timestep_fs': system.timestep_fs,
        'temperature_K': system.temperature_K,
        'steps_per_block': steps, 'rounds': settings.rounds,
        'per_step_seconds': wall, 'per_step_cpu_seconds': cpu,
        'median_seconds': median,
        'median_cpu_seconds': {k: statistics.median(v)
                               for k, v in cpu.items()},
        'spread': {k: (max(v) - min(v)) / statistics.median(v)
                   for k, v in wall.items()},
        'get_forces_again_seconds': forces_again,
    }
    print(f'  {system.calculator:10s} N={len(template):5d} S={steps:4d}  '
          + '  '.join(f'{k}={v * 1e6:.0f}µs' for k, v in median.items()),
          flush=True)
    return result


def run(quick):
    lengths = QUICK if quick else FULL
    speed = SPEED_QUICK if quick else SPEED_FULL
    # The machine is shared: the load around each part goes with it.
    load = {'start': os.getloadavg()}
    print('  sampling and round trips:', flush=True)
    systems_ = [sampling_system(s, lengths) for s in SYSTEMS]
    load['before_cost'] = os.getloadavg()
    print('  cost per step:', flush=True)
    costs = [speed_case(s, r, speed)
             for s, r in (QUICK_SPEED_CASES if quick else SPEED_CASES)]
    load['before_bussi'] = os.getloadavg()
    print('  Bussi:', flush=True)
    bussi = run_bussi(quick)
    load['end'] = os.getloadavg()
    return {
        'load_average': load,
        'settings': {'friction_per_fs': FRICTION_PER_FS, 'seed': SEED,
                     'blocks': BLOCKS, 'window_c': WINDOW_C,
                     'force_every': FORCE_EVERY,
                     'temperature_goal_percent': TEMPERATURE_GOAL_PERCENT,
                     'bits_goal_ratio': BITS_GOAL_RATIO,
                     'trajectory_bytes_per_coordinate':
                         TRAJECTORY_BYTES_PER_COORDINATE,
                     **{f'lengths_{k}': v for k, v in asdict(lengths).items()},
                     'speed': asdict(speed)},
        'systems': systems_,
        'speed': costs,
        'bussi': bussi,
    }


if __name__ == '__main__':
    import run_all
    sys.exit(run_all.main(['--only', 'thermostat'] + sys.argv[1:]))
