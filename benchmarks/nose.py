"""ReversibleNose against ASE's thermostats: sampling, exact reversal,
memory, cost.

A section of ``run_all.py``::

    python benchmarks/run_all.py --only nose           # 12-15 minutes
    python benchmarks/run_all.py --quick --only nose   # ~15 s

(703 s and 923 s measured on the 2-core machine at a load average of 2 to
3.5, another job running beside it.)

Systems: those of ``thermostat.py`` -- periodic fcc argon (asap3
LennardJones, 80 K) and copper (asap3 EMT, 600 K, no rattle), 256 atoms
each -- both at 5 fs, with ``tdamp`` = ``TDAMP_STEPS`` time steps.

Where the run starts matters for Nosé in virtual time.  ``s`` is not
pulled towards 1: it ends wherever the extended energy puts it, ``g kT ln
s`` taking up whatever energy the thermostat had to add or remove, and the
real time step is ``dt / s``.  From a perfect lattice with momenta drawn
at T, equipartition leaves the atoms near T / 2, the thermostat pours in
about 1.5 N kT and ``s`` falls to about 0.6.  So the momenta are drawn at
``START_FACTOR`` times the target on the lattice, which equipartition turns
into about T, and ``s`` (its mean and range) and ``dt / s`` are reported.

1. Sampling.  ReversibleNose and ASE's ``Langevin`` (``thermostat.run_ase``:
   friction 0.01 / fs, ``FixCom``, seed 7) run the same number of steps
   from the same atoms; ReversibleNose's sampling run is the forward half
   of the round trip (2.).  After ``equilibration`` steps every step is a
   sample, analysed by ``thermostat.statistics_of``: the mean internal
   kinetic temperature (3N - 3 degrees of freedom, what ReversibleNose's
   ``N_f`` counts: both keep the centre of mass at rest), a
   Kolmogorov-Smirnov test of the internal kinetic energy against
   Gamma((3N - 3) / 2, kT) on samples thinned to ``ceil(2 g)``, and the
   mean potential energy against ASE Langevin's.  Besides, ``s`` every
   step and the extended energy every ``FORCE_EVERY`` steps.
2. Exact reversal: after the sampling run, ``reverse()`` and as many steps
   back with no observer; every entry of ``dyn.counts`` (positions,
   virtual momenta, ``s``, ``pi``, the clock) is compared with the counts
   right after the constructor with ``np.array_equal``, and so are the
   positions and momenta the atoms show.
3. Memory against steps, Ar 256 only (to keep the section's time: the
   adjoint's finite-difference products cost two force calls a step):
   one fresh process per point (``--memory-worker``) that builds the
   system, constructs the integrator and only then starts ``tracemalloc``.
   ReversibleNose: the traced peak of ``run(N)``, then, with the peak
   reset, of ``backpropagate(N, ...)`` (a fixed random loss gradient,
   finite-difference Hessian-vector products: asap3 has no analytic
   Hessian), the memory still held after each, then the counts compared
   with the start's.  ReversibleLangevin, one process: its buffers
   (``thermostat.buffer_sizes``) and the traced memory at the same steps.
   A peak is the largest transient a run met, and some transients are
   rare (the energy check every ``ENERGY_CHECK_INTERVAL`` steps, the
   purity spot check every ``SPOT_CHECK_INTERVAL`` force calls),
   so flatness is judged from the last two points, and one more process
   profiles the traced peak step by step to show which steps make them.
   Two workers run at a time; their times are not compared with
   anything.
4. Cost per step: ReversibleNose, ASE ``NoseHooverChainNVT`` (same tdamp),
   ASE Langevin, ASE VelocityVerlet and ReversibleVerlet, copper with
   asap3 EMT at 1000 and 4000 atoms, interleaved rounds by
   ``thermostat.speed_case``.

Two studies run on their own and are kept by the section's runs
(``python benchmarks/nose.py --study timestep`` or ``chain``: 807 s and
743 s measured at a load average of 3 to 4), rendered into
docs/thermostats.md:

5. Large time steps: Au 256 (asap3 EMT), momenta drawn at 600 K,
   thermostats at 300 K with tdamp = 100 steps, at 2, 5, 10 and 20 fs:
   ReversibleNose's two schemes, the velocity scheme with a chain of 3,
   and ASE's ``NoseHooverChainNVT``; 5,000 steps, then 40,000 sampled
   every 5: the mean on-step temperature, that of the half-kicked momenta
   ``(p' + dt F / 2) / s`` (what the velocity scheme's thermostat reads),
   and the mean and spread of the potential energy.
6. The chain: first, from the tests' round-trip systems (Cu 108, Ar 256)
   at tdamp 10 to 100 steps, whether a chain of 3 runs 3,000 steps where
   the single thermostat does; then the sampling of copper (as in 1.) and
   liquid argon (256 atoms at rho sigma**3 = 0.84, 120 K, melted by ASE's
   Langevin) with tchain 1, 2 and 3: KS tests of the on-step kinetic
   energy (scale kT, and scale from its mean) and of the half-kicked one,
   the extended energy, every ``s_j``'s range, a round trip for tchain 3,
   and the cost per step against the single thermostat and ASE's chain.
"""

from __future__ import annotations

import common  # noqa: F401  (first: pins BLAS threads before numpy)

import copy
import gc
import json
import math
import os
import sys
import time
import tracemalloc
import warnings
from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np
import thermostat
from adjoint import _max_rss_bytes
from ase import units
from ase.build import bulk
from ase.md.langevin import Langevin
from ase.md.nose_hoover_chain import NoseHooverChainNVT
from ase.md.velocitydistribution import (MaxwellBoltzmannDistribution,
                                         Stationary)
from thermostat import (BLOCKS, FORCE_EVERY, SPEED_FULL, SPEED_QUICK,
                        TEMPERATURE_GOAL_PERCENT,
                        TRAJECTORY_BYTES_PER_COORDINATE, WINDOW_C, Sampler,
                        block_mean, buffer_sizes, histogram_edges,
                        integrated_time, run_ase, speed_case, statistics_of)

from ase_reversible import ReversibleNose
from ase_reversible.app.systems import argon_bulk, copper_bulk, thermalize
from ase_reversible.md.nose.dynamics import ENERGY_CHECK_INTERVAL
from ase_reversible.md.nose.thermostat import CHAIN_STIFFNESS
from ase_reversible.purity import SPOT_CHECK_INTERVAL

#: The momenta are drawn at this multiple of the target temperature (top).
START_FACTOR = 2.0
TIMESTEP_FS = 5.0
#: The thermostat's time in time steps.
TDAMP_STEPS = 40
#: Seed of the memory workers' loss gradient.
LOSS_SEED = 1
#: Steps between stored values of s for the plot.
TRACE_EVERY = 100
#: Steps of the per-step memory profile reported, the largest peaks.
PROFILE_LARGEST = 12
#: The goals judged on the page (the temperature goal is thermostat.py's).
KS_LEVEL = 0.01
POTENTIAL_GOAL_SE = 2.0
MEMORY_GOAL_RATIO = 1.1
COST_GOAL_RATIO = 1.05
MEMORY_PARALLEL = 2


def drawn_hot(build, **options):
    """``build`` with the momenta drawn at ``START_FACTOR`` times the
    temperature it is given."""
    def built(repeat, temperature_K):
        return build(repeat, START_FACTOR * temperature_K, **options)
    return built


#: thermostat.py's systems, at 5 fs, on the bare lattice, drawn hot.
SYSTEMS = (
    replace(thermostat.SYSTEMS[0], build=drawn_hot(argon_bulk),
            timestep_fs=TIMESTEP_FS),
    replace(thermostat.SYSTEMS[1], build=drawn_hot(copper_bulk, rattle=0),
            timestep_fs=TIMESTEP_FS),
)
MEMORY_SYSTEM = SYSTEMS[0]


@dataclass(frozen=True)
class Lengths:
    equilibration: int
    round_trip: int          # forward steps, equilibration included
    memory_steps: tuple
    profile_steps: int


FULL = Lengths(equilibration=2000, round_trip=100_000,
               memory_steps=(1000, 10_000, 100_000), profile_steps=4096)
QUICK = Lengths(equilibration=200, round_trip=1000, memory_steps=(100, 1000),
                profile_steps=1024)

#: Copper, asap3 EMT: 1000 and 4000 atoms.
SPEED_CASES = ((SYSTEMS[1], (5, 5, 10)), (SYSTEMS[1], (10, 10, 10)))
QUICK_SPEED_CASES = SPEED_CASES[:1]
CHAIN_SPEED_CONTESTANTS = ('reversible_nose', 'reversible_nose_tchain3',
                           'ase_nose_hoover_chain', 'velocity_verlet')
SPEED_CONTESTANTS = ('reversible_nose', 'ase_nose_hoover_chain',
                     'ase_langevin', 'velocity_verlet', 'reversible_verlet')


# -- the integrators ----------------------------------------------------------

def tdamp(system):
    return TDAMP_STEPS * system.timestep_fs * units.fs


def reversible_nose(atoms, system):
    return ReversibleNose(atoms, system.timestep_fs * units.fs,
                          system.temperature_K, tdamp(system))


def ase_nose_hoover_chain(atoms, system):
    return NoseHooverChainNVT(atoms, system.timestep_fs * units.fs,
                              temperature_K=system.temperature_K,
                              tdamp=tdamp(system))


def reversible_nose_chain(atoms, system):
    return ReversibleNose(atoms, system.timestep_fs * units.fs,
                          system.temperature_K, tdamp(system), tchain=3)


INTEGRATORS = {'reversible_nose': reversible_nose,
               'reversible_nose_tchain3': reversible_nose_chain,
               'ase_nose_hoover_chain': ase_nose_hoover_chain,
               **thermostat.INTEGRATORS}


# -- sampling and the round trip ---------------------------------------------

class NoseSampler(Sampler):
    """thermostat.Sampler, plus ``s`` every step and the extended energy
    every ``FORCE_EVERY`` steps."""

    def __init__(self, dyn, steps):
        super().__init__(dyn, steps)
        self.s = np.full(steps + 1, np.nan)
        self.extended = np.full(steps + 1, np.nan)

    def __call__(self):
        super().__call__()
        i = self.dyn.nsteps
        self.s[i] = self.dyn.thermostat_position
        if i % FORCE_EVERY == 0:
            self.extended[i] = self.dyn.get_conserved_energy()


def thermostat_statistics(sampler, first, timestep_fs):
    """``s``, the real time step and the extended energy."""
    s_all = sampler.s
    s = s_all[first:]
    inverse_square = float(np.mean(1.0 / s**2))
    extended = sampler.extended[np.isfinite(sampler.extended)]
    return {
        's': {**block_mean(s), 'std': float(s.std()),
              'min': float(s.min()), 'max': float(s.max()),
              'correlation_time_steps': integrated_time(s)},
        's_from_start': {'min': float(s_all.min()), 'max': float(s_all.max()),
                         'first': float(s_all[0])},
        'real_timestep_fs': {'mean': float(np.mean(timestep_fs / s)),
                             'min': float(timestep_fs / s.max()),
                             'max': float(timestep_fs / s.min()),
                             'rms': timestep_fs * math.sqrt(inverse_square)},
        's_trace_every': TRACE_EVERY,
        's_trace': s_all[::TRACE_EVERY].tolist(),
        'extended_energy_eV': {
            'first': float(extended[0]), 'last': float(extended[-1]),
            'max_deviation': float(np.max(np.abs(extended - extended[0]))),
            'std': float(extended.std())},
    }


def run_nose(system, lengths):
    """ReversibleNose's sampling run, then the same steps back."""
    atoms = system.atoms()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter('always')
        dyn = reversible_nose(atoms, system)
        start = dyn.counts
        x0_nc, p0_nc = atoms.get_positions(), atoms.get_momenta()
        sampler = NoseSampler(dyn, lengths.round_trip)
        dyn.attach(sampler, interval=1)
        tic = time.perf_counter()
        dyn.run(lengths.round_trip)
        forward_seconds = time.perf_counter() - tic
        real_time = dyn.get_time()
        moved = not np.array_equal(atoms.get_positions(), x0_nc)
        dyn.observers.clear()  # the way back is a plain run
        dyn.reverse()
        tic = time.perf_counter()
        dyn.run(lengths.round_trip)
        back_seconds = time.perf_counter() - tic
    end = dyn.counts
    round_trip = {
        'steps_each_way': lengths.round_trip,
        'moved': moved,
        'counts_equal': {name: bool(np.array_equal(end[name], start[name]))
                         for name in start},
        'positions_equal': bool(np.array_equal(atoms.get_positions(),
                                               x0_nc)),
        'momenta_equal': bool(np.array_equal(atoms.get_momenta(), p0_nc)),
        'time_after_fs': dyn.get_time() / units.fs,
        'real_time_forward_fs': real_time / units.fs,
        'forward_seconds': forward_seconds,
        'back_seconds': back_seconds,
        'warnings': sorted({f'{w.category.__name__}: {w.message}'
                            for w in caught}),
    }
    thermostat_ = {'degrees_of_freedom': dyn.degrees_of_freedom,
                   'tdamp_fs': dyn.tdamp / units.fs}
    return sampler, round_trip, thermostat_


def sampling_system(system, lengths):
    n_atoms = 4 * int(np.prod(system.repeat))
    dof = 3 * n_atoms - 3
    kT = units.kB * system.temperature_K
    edges = histogram_edges(dof, kT)
    ours, round_trip, thermostat_ = run_nose(system, lengths)
    theirs, ase_seconds = run_ase(system, lengths.round_trip)
    first = lengths.equilibration + 1
    h = system.timestep_fs * units.fs
    sampled = {'reversible_nose': statistics_of(ours, first, dof, kT, edges,
                                                h),
               'ase_langevin': statistics_of(theirs, first, dof, kT, edges,
                                             h)}
    sampled['ase_langevin']['seconds'] = ase_seconds
    thermostat_.update(thermostat_statistics(ours, first, system.timestep_fs))
    # The pi kicks read the momenta between the two half kicks, so those
    # are what the thermostat steers to T; for a harmonic mode the momenta
    # at the step's end are then cooler by (h omega)**2 / 4, h = dt / s.
    real_rms = thermostat_['real_timestep_fs']['rms']
    omega2 = sampled['reversible_nose']['mean_omega_squared_per_fs2']
    thermostat_['harmonic_kinetic_offset_percent'] = (
        -100 * real_rms**2 * omega2 / 4)
    a = sampled['reversible_nose']['potential_energy']
    b = sampled['ase_langevin']['potential_energy']
    se = math.hypot(a['standard_error'], b['standard_error'])
    result = {
        'system': system.label, 'calculator': system.calculator,
        'n_atoms': n_atoms, 'dof': dof,
        'temperature_K': system.temperature_K,
        'start_temperature_K': START_FACTOR * system.temperature_K,
        'timestep_fs': system.timestep_fs, 'kT_eV': kT,
        'equilibration_steps': lengths.equilibration,
        'histogram_edges_eV': edges.tolist(),
        'sampling': sampled,
        'thermostat': thermostat_,
        'potential_difference_eV': a['mean'] - b['mean'],
        'potential_difference_standard_error_eV': se,
        'round_trip': round_trip,
    }
    t_ours = sampled['reversible_nose']['temperature_K']['mean']
    t_ase = sampled['ase_langevin']['temperature_K']['mean']
    s = thermostat_['s']
    d = a['mean'] - b['mean']
    print(f'  {system.label:7s} N={n_atoms}  T_kin {t_ours:.2f} / '
          f'{t_ase:.2f} K  KS p '
          f"{sampled['reversible_nose']['ks']['p_value']:.3g}  s "
          f"{s['mean']:.3f} [{s['min']:.3f}, {s['max']:.3f}]  dE_pot "
          f'{d:+.4f} eV ({d / se:+.1f} SE)  exact '
          f'{all(round_trip["counts_equal"].values())}  '
          f'{round_trip["forward_seconds"] + round_trip["back_seconds"]:.0f}'
          f' + {ase_seconds:.0f} s', flush=True)
    return result


# -- memory -----------------------------------------------------------------

def loss_gradient(n_atoms):
    rng = np.random.default_rng(LOSS_SEED)
    return rng.standard_normal((n_atoms, 3)), rng.standard_normal((n_atoms, 3))


class WarningTally:
    """Stands in for ``warnings.showwarning``: counts the warnings by
    category and keeps the first message of each, in constant memory (a
    list of every warning would grow with the steps it measures)."""

    def __init__(self):
        self.count, self.first = {}, {}

    def __call__(self, message, category, *args, **kwargs):
        name = category.__name__
        self.count[name] = self.count.get(name, 0) + 1
        self.first.setdefault(name, str(message))

    def summary(self):
        return sorted(f'{name} (x{n}): {self.first[name]}'
                      for name, n in self.count.items())


def _resident_bytes():
    """The process's resident set size now (Linux), or None."""
    try:
        with open('/proc/self/statm') as f:
            return int(f.read().split()[1]) * os.sysconf('SC_PAGE_SIZE')
    except (OSError, ValueError, IndexError):
        return None


def nose_memory_worker(steps):
    """One ReversibleNose point: run(N), then backpropagate(N)."""
    atoms = MEMORY_SYSTEM.atoms()
    dyn = reversible_nose(atoms, MEMORY_SYSTEM)
    start = dyn.counts
    grad_x, grad_p = loss_gradient(len(atoms))
    gc.collect()
    rss_before = _max_rss_bytes()
    resident = [_resident_bytes()]
    tally = WarningTally()
    with warnings.catch_warnings():
        warnings.simplefilter('always')
        warnings.showwarning = tally
        tracemalloc.start()
        t0 = time.perf_counter()
        dyn.run(steps)
        t1 = time.perf_counter()
        forward_current, forward_peak = tracemalloc.get_traced_memory()
        rss_forward = _max_rss_bytes()
        resident.append(_resident_bytes())
        tracemalloc.reset_peak()
        gradients = dyn.backpropagate(steps, grad_x, grad_p)
        t2 = time.perf_counter()
        current, peak = tracemalloc.get_traced_memory()
        own = tracemalloc.get_tracemalloc_memory()
        tracemalloc.stop()
    resident.append(_resident_bytes())
    end = dyn.counts
    gx_nc, gp_nc = gradients
    return {
        'kind': 'nose', 'steps': steps, 'atoms': len(atoms),
        'forward_traced_peak_bytes': forward_peak,
        'forward_traced_end_bytes': forward_current,
        'backpropagate_traced_peak_bytes': peak,
        'backpropagate_traced_end_bytes': current,
        'tracemalloc_own_bytes': own,
        'max_rss_before_bytes': rss_before,
        'max_rss_after_forward_bytes': rss_forward,
        'max_rss_bytes': _max_rss_bytes(),
        # before, after run, after backpropagate
        'resident_bytes': resident,
        'forward_seconds': t1 - t0, 'backpropagate_seconds': t2 - t1,
        'hessian_vector_products': gradients.hessian_vector_products,
        'counts_equal_after_backpropagate': all(
            np.array_equal(end[k], start[k]) for k in start),
        'gradient_finite': bool(np.isfinite(gx_nc).all()
                                and np.isfinite(gp_nc).all()),
        'gradient_max_abs': float(max(np.abs(gx_nc).max(),
                                      np.abs(gp_nc).max())),
        'warnings': tally.summary(),
    }


class PeakPerStep:
    """Observer: the traced peak of each step, reset after reading."""

    def __init__(self, dyn, steps):
        self.dyn = dyn
        self.peak = np.zeros(steps + 1, np.int64)

    def __call__(self):
        self.peak[self.dyn.nsteps] = tracemalloc.get_traced_memory()[1]
        tracemalloc.reset_peak()


def profile_memory_worker(steps):
    """Which steps of a ReversibleNose run allocate most: a transient is
    in the peak of a run only once a run has been long enough to meet it,
    which the points above cannot tell from growth."""
    atoms = MEMORY_SYSTEM.atoms()
    dyn = reversible_nose(atoms, MEMORY_SYSTEM)
    observer = PeakPerStep(dyn, steps)
    dyn.attach(observer, interval=1)
    gc.collect()
    with warnings.catch_warnings():
        warnings.simplefilter('always')
        warnings.showwarning = WarningTally()
        tracemalloc.start()
        dyn.run(steps)
        tracemalloc.stop()
    peak = observer.peak[1:]  # step 0 holds the constructor's leftovers
    median = float(np.median(peak))
    largest = np.argsort(peak, kind='stable')[::-1][:PROFILE_LARGEST]
    return {'kind': 'profile', 'steps': steps, 'atoms': len(atoms),
            'median_step_peak_bytes': median,
            'largest': [{'step': int(i) + 1, 'peak_bytes': int(peak[i])}
                        for i in sorted(largest)],
            'spot_check_interval': SPOT_CHECK_INTERVAL,
            'energy_check_interval': ENERGY_CHECK_INTERVAL}


def langevin_memory_worker(checkpoints):
    """ReversibleLangevin on the same system: buffers at each checkpoint."""
    atoms = MEMORY_SYSTEM.atoms()
    dyn = thermostat.reversible_langevin(atoms, MEMORY_SYSTEM)
    coordinates = 3 * len(atoms)
    gc.collect()
    rss_before = _max_rss_bytes()
    resident_before = _resident_bytes()
    points, done = [], 0
    tally = WarningTally()
    with warnings.catch_warnings():
        warnings.simplefilter('always')
        warnings.showwarning = tally
        tracemalloc.start()
        t0 = time.perf_counter()
        for stop in checkpoints:
            dyn.run(stop - done)
            done = stop
            current, peak = tracemalloc.get_traced_memory()
            points.append({**buffer_sizes(dyn, stop, coordinates),
                           'traced_bytes': current,
                           'traced_peak_bytes': peak,
                           'resident_bytes': _resident_bytes(),
                           'max_rss_bytes': _max_rss_bytes()})
        seconds = time.perf_counter() - t0
        tracemalloc.stop()
    return {'kind': 'langevin', 'atoms': len(atoms),
            'max_rss_before_bytes': rss_before,
            'resident_before_bytes': resident_before, 'seconds': seconds,
            'checkpoints': points, 'warnings': tally.summary()}


def _run_worker(kind, steps):
    return common.run_worker(Path(__file__).resolve(),
                             ['--memory-worker', kind, *steps])


def measure_memory(lengths):
    steps = lengths.memory_steps
    # Longest first, so the two workers finish together.
    jobs = [('nose', (steps[-1],)), ('langevin', steps)] + [
        ('nose', (n,)) for n in reversed(steps[:-1])] + [
        ('profile', (lengths.profile_steps,))]
    with ThreadPoolExecutor(MEMORY_PARALLEL) as pool:
        futures = [pool.submit(_run_worker, *job) for job in jobs]
        raw = [f.result() for f in futures]
    nose = sorted((r for r in raw if r['kind'] == 'nose'),
                  key=lambda r: r['steps'])
    langevin = next(r for r in raw if r['kind'] == 'langevin')
    profile = next(r for r in raw if r['kind'] == 'profile')
    system = MEMORY_SYSTEM
    for r in nose + langevin['checkpoints']:
        r['trajectory_bytes'] = (TRAJECTORY_BYTES_PER_COORDINATE
                                 * 3 * nose[0]['atoms'] * r['steps'])
    print('  memory: ' + '  '.join(
        f"N={r['steps']} run {r['forward_traced_peak_bytes'] / 1e3:.0f} kB "
        f"adjoint {r['backpropagate_traced_peak_bytes'] / 1e3:.0f} kB"
        for r in nose) + '  Langevin buffer ' + ', '.join(
        f"{c['nbytes'] / 1e3:.0f} kB" for c in langevin['checkpoints']),
        flush=True)
    return {'system': system.label, 'calculator': system.calculator,
            'n_atoms': nose[0]['atoms'],
            'temperature_K': system.temperature_K,
            'timestep_fs': system.timestep_fs,
            'friction_per_fs': thermostat.FRICTION_PER_FS,
            'parallel_workers': MEMORY_PARALLEL,
            'nose': nose, 'langevin': langevin, 'profile': profile}


# -- large time steps: which momenta the thermostat holds at T --------------

#: Au 256, asap3 EMT, momenta drawn at 600 K, thermostats at 300 K with
#: tdamp = TIMESTEP_STUDY_TDAMP_STEPS steps; 2 fs is the reference.
TIMESTEP_STUDY_FS = (2.0, 5.0, 10.0, 20.0)
TIMESTEP_STUDY_TDAMP_STEPS = 100
TIMESTEP_STUDY_EVERY = 5
#: ReversibleNose's schemes (and the velocity scheme with a chain of 3),
#: and ASE's chain.
TIMESTEP_STUDY_KINDS = ('velocity', 'position', 'velocity-tchain3',
                        'ase_nose_hoover_chain')


@dataclass(frozen=True)
class StudyLengths:
    equilibration: int
    sampled: int


TIMESTEP_FULL = StudyLengths(equilibration=5000, sampled=40_000)
TIMESTEP_QUICK = StudyLengths(equilibration=200, sampled=1000)


def gold_256():
    atoms = bulk('Au', 'fcc', a=4.08, cubic=True).repeat((4, 4, 4))
    MaxwellBoltzmannDistribution(atoms, temperature_K=600,
                                 rng=np.random.default_rng(1))
    Stationary(atoms)
    atoms.calc = thermostat.CALCULATORS['asap3 EMT']()
    return atoms


class StepSampler:
    """Observer: the on-step kinetic temperature, the temperature of the
    momenta half kicked by the step's forces, ``(p' + h F / 2) / s``
    (what the velocity scheme's thermostat reads), and the potential
    energy."""

    def __init__(self, dyn, dof):
        self.dyn, self.atoms = dyn, dyn.atoms
        self.m_n1 = self.atoms.get_masses()[:, None]
        self.scale = 1.0 / (dof * units.kB)
        self.on, self.half, self.potential = [], [], []

    def __call__(self):
        p_nc = self.atoms.get_momenta()
        self.on.append(float((p_nc * p_nc / self.m_n1).sum()) * self.scale)
        s = getattr(self.dyn, 'thermostat_position', None)
        if s is not None:
            f_nc = self.atoms.get_forces()
            h_nc = p_nc + (0.5 * self.dyn.dt / s) * f_nc
            self.half.append(float((h_nc * h_nc / self.m_n1).sum())
                             * self.scale)
        self.potential.append(self.atoms.get_potential_energy())


def timestep_case(kind, dt_fs, lengths):
    """One run of the study: ``kind`` is a ReversibleNose scheme or
    ``'ase_nose_hoover_chain'``."""
    atoms = gold_256()
    dof = 3 * len(atoms) - 3
    dt = dt_fs * units.fs
    tdamp_ = TIMESTEP_STUDY_TDAMP_STEPS * dt
    if kind == 'ase_nose_hoover_chain':
        dyn = NoseHooverChainNVT(atoms, dt, temperature_K=300, tdamp=tdamp_)
    else:
        scheme, _, chain = kind.partition('-tchain')
        dyn = ReversibleNose(atoms, dt, temperature_K=300, tdamp=tdamp_,
                             scheme=scheme, tchain=int(chain or 1))
    tic = time.perf_counter()
    dyn.run(lengths.equilibration)
    sampler = StepSampler(dyn, dof)
    dyn.attach(sampler, interval=TIMESTEP_STUDY_EVERY)
    dyn.run(lengths.sampled)
    seconds = time.perf_counter() - tic
    potential = np.array(sampler.potential[1:])
    result = {'kind': kind, 'timestep_fs': dt_fs, 'seconds': seconds,
              'samples': len(potential),
              'temperature_K': block_mean(sampler.on[1:]),
              'potential_energy_eV': block_mean(potential),
              'potential_std_eV': float(potential.std())}
    if sampler.half:
        result['half_kick_temperature_K'] = block_mean(sampler.half[1:])
    if hasattr(dyn, 'thermostat_position'):
        result['s_last'] = dyn.thermostat_position
    half = result.get('half_kick_temperature_K', {}).get('mean', math.nan)
    t_on = result['temperature_K']['mean']
    u = result['potential_energy_eV']
    print(f'  {kind:22s} {dt_fs:4g} fs  T {t_on:.2f} K (half kick '
          f"{half:.2f})  U {u['mean']:.3f} +- {u['standard_error']:.3f} eV"
          f'  {seconds:.0f} s', flush=True)
    return result


def timestep_study(quick):
    """Mean on-step temperature and potential energy of ReversibleNose's
    two schemes and ASE's chain against the time step."""
    lengths = TIMESTEP_QUICK if quick else TIMESTEP_FULL
    steps = TIMESTEP_STUDY_FS[::3] if quick else TIMESTEP_STUDY_FS
    cases = [timestep_case(kind, dt_fs, lengths) for dt_fs in steps
             for kind in TIMESTEP_STUDY_KINDS]
    return {'system': 'Au 256, asap3 EMT, momenta drawn at 600 K',
            'temperature_K': 300.0,
            'tdamp_steps': TIMESTEP_STUDY_TDAMP_STEPS,
            'sample_every': TIMESTEP_STUDY_EVERY,
            'lengths': asdict(lengths), 'blocks': BLOCKS, 'cases': cases}


# -- cost per step ------------------------------------------------------------

def cost_case(system, repeat, settings):
    result = speed_case(system, repeat, settings, names=SPEED_CONTESTANTS,
                        integrators=INTEGRATORS,
                        reference='ase_nose_hoover_chain')
    result['tdamp_fs'] = tdamp(system) / units.fs
    return result


def run(quick):
    lengths = QUICK if quick else FULL
    speed = SPEED_QUICK if quick else SPEED_FULL
    # The machine is shared: the load around each part goes with it.
    load = {'start': os.getloadavg()}
    print('  sampling and round trips:', flush=True)
    systems_ = [sampling_system(s, lengths) for s in SYSTEMS]
    load['before_memory'] = os.getloadavg()
    memory = measure_memory(lengths)
    load['before_cost'] = os.getloadavg()
    print('  cost per step:', flush=True)
    costs = [cost_case(s, r, speed)
             for s, r in (QUICK_SPEED_CASES if quick else SPEED_CASES)]
    load['end'] = os.getloadavg()
    return {
        **stored_studies(),
        'load_average': load,
        'settings': {'start_factor': START_FACTOR,
                     'tdamp_steps': TDAMP_STEPS,
                     'langevin_friction_per_fs': thermostat.FRICTION_PER_FS,
                     'langevin_seed': thermostat.SEED,
                     'blocks': BLOCKS, 'window_c': WINDOW_C,
                     'force_every': FORCE_EVERY,
                     'temperature_goal_percent': TEMPERATURE_GOAL_PERCENT,
                     'ks_level': KS_LEVEL,
                     'potential_goal_standard_errors': POTENTIAL_GOAL_SE,
                     'memory_goal_ratio': MEMORY_GOAL_RATIO,
                     'cost_goal_ratio': COST_GOAL_RATIO,
                     'loss_seed': LOSS_SEED,
                     **{f'lengths_{k}': v for k, v in asdict(lengths).items()},
                     'speed': asdict(speed)},
        'systems': systems_,
        'memory': memory,
        'speed': costs,
    }


# -- the chain: canonical on a crystal? --------------------------------------

#: Liquid argon: fcc at rho sigma**3 = 0.84 (sigma 3.405 Å), 120 K (kT /
#: epsilon = 1.0), melted by ASE's Langevin before the thermostat starts.
AR_LIQUID_LATTICE = 5.73
AR_LIQUID_MELT_STEPS = 2000
CHAIN_LENGTHS = (1, 2, 3)
CHAIN_FULL = StudyLengths(equilibration=2000, sampled=60_000)
CHAIN_QUICK = StudyLengths(equilibration=200, sampled=1000)


def liquid_argon(repeat, temperature_K):
    atoms = bulk('Ar', 'fcc', a=AR_LIQUID_LATTICE, cubic=True) * repeat
    thermalize(atoms, temperature_K, seed=thermostat.SEED)
    atoms.calc = thermostat.CALCULATORS['asap3 LJ']()
    Langevin(atoms, 10 * units.fs, temperature_K=temperature_K,
             friction=0.01 / units.fs,
             rng=np.random.default_rng(thermostat.SEED)).run(
        AR_LIQUID_MELT_STEPS)
    atoms.calc = None
    return atoms


CHAIN_SYSTEMS = (
    SYSTEMS[1],
    replace(thermostat.SYSTEMS[0], label='Ar liquid', build=liquid_argon,
            temperature_K=120.0, timestep_fs=10.0),
)


class ChainSampler(NoseSampler):
    """NoseSampler, plus the range of every ``s_j`` and the internal
    kinetic energy of the momenta half kicked, ``(p' + h F / 2) / s_1``
    (what the velocity scheme's thermostat reads)."""

    def __init__(self, dyn, steps):
        super().__init__(dyn, steps)
        self.low = np.full(dyn.tchain, np.inf)
        self.high = np.zeros(dyn.tchain)
        self.half_kinetic = np.full(steps + 1, np.nan)
        self.m_n1 = self.atoms.get_masses()[:, None]

    def __call__(self):
        super().__call__()
        s_j = self.dyn.thermostat_positions
        np.minimum(self.low, s_j, out=self.low)
        np.maximum(self.high, s_j, out=self.high)
        p_nc = self.atoms.get_momenta() + (0.5 * self.dyn.dt / s_j[0]) * \
            self.atoms.get_forces()
        p_c = p_nc.sum(axis=0)
        self.half_kinetic[self.dyn.nsteps] = 0.5 * (
            float((p_nc * p_nc / self.m_n1).sum())
            - float(p_c @ p_c) / self.total_mass)


def chain_case(system, tchain, scheme, lengths):
    atoms = system.atoms()
    n_atoms = len(atoms)
    dof = 3 * n_atoms - 3
    kT = units.kB * system.temperature_K
    h = system.timestep_fs * units.fs
    dyn = ReversibleNose(atoms, h, system.temperature_K, tdamp(system),
                         tchain=tchain, scheme=scheme)
    steps = lengths.equilibration + lengths.sampled
    start = dyn.counts
    x0_nc = atoms.get_positions()
    sampler = ChainSampler(dyn, steps)
    dyn.attach(sampler, interval=1)
    tic = time.perf_counter()
    try:
        dyn.run(steps)
    except Exception as error:  # what it raised is the result
        failure = f'{type(error).__name__} at step {dyn.nsteps}'
        print(f'  {system.label:9s} tchain {tchain} {scheme:8s} {failure}',
              flush=True)
        return {'system': system.label, 'n_atoms': n_atoms,
                'tchain': tchain, 'scheme': scheme,
                'timestep_fs': system.timestep_fs,
                'temperature_K': system.temperature_K, 'failure': failure,
                's_range': [[float(a), float(b)] for a, b in
                            zip(sampler.low, sampler.high)]}
    seconds = time.perf_counter() - tic
    first = lengths.equilibration + 1
    displacement = atoms.get_positions() - x0_nc
    result = {
        'system': system.label, 'n_atoms': n_atoms, 'tchain': tchain,
        'scheme': scheme, 'timestep_fs': system.timestep_fs,
        'temperature_K': system.temperature_K,
        'sampling': statistics_of(sampler, first, dof, kT,
                                  histogram_edges(dof, kT), h),
        'thermostat': thermostat_statistics(sampler, first,
                                            system.timestep_fs),
        's_range': [[float(a), float(b)]
                    for a, b in zip(sampler.low, sampler.high)],
        'mean_square_displacement_A2': float(
            np.mean(np.sum(displacement**2, axis=1))),
        'seconds': seconds}
    del result['thermostat']['s_trace']
    half = copy.copy(sampler)
    half.kinetic = sampler.half_kinetic
    half_stats = statistics_of(half, first, dof, kT, histogram_edges(dof, kT),
                               h)
    result['half_kicked'] = {'temperature_K': half_stats['temperature_K'],
                             'ks': half_stats['ks']}
    if tchain == max(CHAIN_LENGTHS):
        dyn.observers.clear()
        dyn.reverse()
        dyn.run(steps)
        result['round_trip_equal'] = {
            name: bool(np.array_equal(dyn.counts[name], start[name]))
            for name in start}
    ks = result['sampling']['ks']
    t = result['sampling']['temperature_K']
    e = result['thermostat']['extended_energy_eV']
    hk = result['half_kicked']
    print(f'  {system.label:9s} tchain {tchain} {scheme:8s} T {t["mean"]:.2f}'
          f' +- {t["standard_error"]:.2f} K  KS p {ks["p_value"]:.3g} (shape '
          f'{ks["shape_p_value"]:.3g}; half kicked T '
          f'{hk["temperature_K"]["mean"]:.2f} p {hk["ks"]["p_value"]:.3g})'
          f'  H drift {e["max_deviation"]:.3g} eV'
          f'  s {result["s_range"]}  {seconds:.0f} s', flush=True)
    return result


#: The stability check: systems (those of the tests' round trips), tdamp
#: in steps, and steps run from the start.
STABILITY_SYSTEMS = (
    replace(thermostat.SYSTEMS[1], label='Cu fcc', repeat=(3, 3, 3),
            build=copper_bulk),
    replace(thermostat.SYSTEMS[0], label='Ar fcc', repeat=(4, 4, 4)),
)
STABILITY_TDAMP_STEPS = (10, 20, 40, 100)
STABILITY_STEPS = 3000


def stability_case(system, tchain, tdamp_steps, steps):
    """From the lattice with momenta at the system's temperature, the
    thermostat at 0.6 times that (what equipartition leaves, about): does
    the run last ``steps`` steps, and how far does the extended energy
    move (kT)?"""
    atoms = system.atoms()
    h = system.timestep_fs * units.fs
    temperature_K = 0.6 * atoms.get_temperature()
    dyn = ReversibleNose(atoms, h, temperature_K, tdamp_steps * h,
                         tchain=tchain, energy_check=0)
    kT = units.kB * temperature_K
    e0 = dyn.get_conserved_energy()
    largest = [0.0]

    def watch():
        largest[0] = max(largest[0], abs(dyn.get_conserved_energy() - e0))
    dyn.attach(watch, interval=5)
    try:
        dyn.run(steps)
        failure = None
    except Exception as error:  # what it raised is the result
        failure = f'{type(error).__name__} at step {dyn.nsteps}'
    result = {'system': system.label, 'n_atoms': len(atoms),
              'timestep_fs': system.timestep_fs, 'tchain': tchain,
              'tdamp_steps': tdamp_steps, 'steps': steps,
              'failure': failure, 'largest_change_kT': largest[0] / kT}
    print(f"  {system.label} {len(atoms)} tchain {tchain} tdamp "
          f"{tdamp_steps:3d} steps: {failure or 'ran'}, |dH| <= "
          f"{result['largest_change_kT']:.3g} kT", flush=True)
    return result


def chain_study(quick, scheme='velocity'):
    lengths = CHAIN_QUICK if quick else CHAIN_FULL
    steps = 300 if quick else STABILITY_STEPS
    stability = [stability_case(system, tchain, tdamp_steps, steps)
                 for system in STABILITY_SYSTEMS
                 for tdamp_steps in STABILITY_TDAMP_STEPS
                 for tchain in (1, 3)]
    cases = [chain_case(system, tchain, scheme, lengths)
             for system in CHAIN_SYSTEMS for tchain in CHAIN_LENGTHS]
    speed = SPEED_QUICK if quick else SPEED_FULL
    cost = speed_case(SYSTEMS[1], (5, 5, 10), speed,
                      names=CHAIN_SPEED_CONTESTANTS, integrators=INTEGRATORS,
                      reference='ase_nose_hoover_chain')
    return {'lengths': asdict(lengths), 'tdamp_steps': TDAMP_STEPS,
            'ks_level': KS_LEVEL, 'chain_stiffness': CHAIN_STIFFNESS,
            'stability': stability, 'cases': cases, 'speed': cost}


STUDIES = {'timestep': timestep_study, 'chain': chain_study}


def stored_studies():
    """The studies stored in docs/benchmarks/nose.json, each with its own
    command and date: a run of the section keeps them (they take longer
    than the rest of it; ``--study`` measures them again)."""
    import common as common_
    path = Path(common_.DOCS) / 'benchmarks' / 'nose.json'
    try:
        results = json.loads(path.read_text())['results']
    except (OSError, ValueError, KeyError):
        return {}
    return {name: results[name] for name in STUDIES if name in results}


def run_study(name, quick, out=None):
    """Measure one study and store it in the nose section's JSON
    (``results[name]``), with its own command, date and load, leaving the
    section's other parts as they were measured."""
    from datetime import datetime
    import common as common_
    path = Path(out or common_.DOCS) / 'benchmarks' / 'nose.json'
    tic = time.perf_counter()
    load = os.getloadavg()
    results = STUDIES[name](quick)
    results.update({
        'command': f'python benchmarks/nose.py --study {name}'
                   + (' --quick' if quick else ''),
        'date': datetime.now().astimezone().isoformat(timespec='seconds'),
        'git_commit': common_.machine_info()['git_commit'],
        'wall_seconds': time.perf_counter() - tic,
        'load_average': {'start': load, 'end': os.getloadavg()}})
    stored = json.loads(path.read_text())
    stored['results'][name] = results
    path.write_text(json.dumps(stored, indent=1) + '\n')
    return results


if __name__ == '__main__':
    if sys.argv[1:2] == ['--study']:
        run_study(sys.argv[2], '--quick' in sys.argv[3:],
                  out=os.environ.get('NOSE_STUDY_OUT'))
        sys.exit(0)
    if sys.argv[1:2] == ['--memory-worker']:
        kind, steps = sys.argv[2], [int(n) for n in sys.argv[3:]]
        if kind == 'langevin':
            worker = langevin_memory_worker(steps)
        else:
            worker = {'nose': nose_memory_worker,
                      'profile': profile_memory_worker}[kind](*steps)
        print(json.dumps(worker), flush=True)
    else:
        import run_all
        sys.exit(run_all.main(['--only', 'nose'] + sys.argv[1:]))
