"""Work against precision: run time to reach a given energy error (the
method: docs/benchmarks.md)."""

from __future__ import annotations

import common  # noqa: F401  (first: pins BLAS threads before numpy)

import functools
import math
import statistics
import time
from dataclasses import dataclass
from typing import Callable

import numpy as np
import systems as bench_systems
from systems import ResultCache
from ase import units
from ase.md.verlet import VelocityVerlet
from scipy.spatial.distance import pdist

from ase_reversible import ReversibleVerlet, purity
from ase_reversible.app import systems as app_systems

#: The relative energy error the summary asks each method to reach.
TARGET = 1e-8
#: A sweep stops once its max error is this fraction of TARGET: the point
#: brackets the target from below with some margin for noisy errors.
STOP_FRACTION = 0.5
#: A sweep also stops when its best error has not improved by FLOOR_GAIN
#: while the step shrank FLOOR_STEP_RATIO times: the error has hit a floor.
#: The guarded mode's floor falls slowly with the step (its momentum
#: quantum is proportional to it), about 2x per 4x: that is not a floor.
FLOOR_GAIN = 1.5
FLOOR_STEP_RATIO = 4.0

#: Larger than the cluster's diameter (22 Å for 147 atoms) with margin.
AR_CUTOFF = 40.0
AR_TEMPERATURE_K, CU_TEMPERATURE_K = 30.0, 300.0


@dataclass(frozen=True)
class Method:
    label: str
    scheme: str | None  # None: ASE's VelocityVerlet
    order: int

    @property
    def stages(self) -> int:
        return 1 if self.scheme is None else stages(self.order)


@functools.cache
def stages(order):
    """Force calls per step of ReversibleVerlet at ``order``, as reported
    by the integrator itself (on a small probe system)."""
    atoms = app_systems.argon_cluster(2, AR_TEMPERATURE_K)
    atoms.calc = app_systems.argon_lj()
    return ReversibleVerlet(atoms, units.fs, order=order).composition.stages


VV = Method('VelocityVerlet', None, 2)


def methods(quick):
    orders = (2, 4, 6, 8) if quick else (2, 4, 6, 8, 10)
    return [VV] + [Method(f'{scheme} {order}', scheme, order)
                   for order in orders for scheme in ('velocity', 'position')]


@dataclass(frozen=True)
class System:
    key: str
    label: str
    build: Callable[[], object]        # thermalised atoms, no calculator
    calc: Callable[[], object]
    interval_fs: float                 # sampling interval = largest step
    simulated_fs: float
    start_fs_per_call: float           # first step of a sweep, per stage
    free: bool


def argon_cluster(shells):
    return functools.partial(app_systems.argon_cluster, shells,
                             AR_TEMPERATURE_K)


#: A fresh bare asap3 LennardJones with the cutoff above, per call.
raw_argon_lj = bench_systems.asap3_argon_lj(AR_CUTOFF)


def systems(quick):
    shells, simulated_ar = (3, 640.0) if quick else (4, 1536.0)
    repeat, simulated_cu = ((3, 3, 3), 96.0) if quick else ((4, 4, 4), 320.0)
    return [
        System('argon_cluster', 'free Ar cluster', argon_cluster(shells),
               lambda: ResultCache(raw_argon_lj()), interval_fs=64.0,
               simulated_fs=simulated_ar, start_fs_per_call=16.0, free=True),
        System('copper_crystal', 'periodic Cu crystal', functools.partial(
                   bench_systems.rgl_copper_crystal, repeat, CU_TEMPERATURE_K),
               bench_systems.copper_rgl, interval_fs=16.0,
               simulated_fs=simulated_cu, start_fs_per_call=4.0, free=False),
    ]


@dataclass(frozen=True)
class Settings:
    ladder: tuple        # steps per sampling interval, coarse to fine
    max_run_seconds: float
    #: Runs shorter than this are repeated (same trajectory, fresh atoms
    #: and calculator), up to `repeats` runs, and timed by the median.
    min_timed_seconds: float
    repeats: int


def _ladder(quick, top=4096):
    # Full mode refines by factors 2, 1.5, 1.33 (about sqrt 2 on average).
    rungs, k = [], 1
    while k <= top:
        rungs.append(k)
        if not quick and k >= 2:
            rungs.append(3 * k // 2)
        k *= 2
    return tuple(sorted(set(rungs)))


QUICK = Settings(_ladder(True), max_run_seconds=2.0, min_timed_seconds=0.1,
                 repeats=3)
FULL = Settings(_ladder(False), max_run_seconds=40.0, min_timed_seconds=0.3,
                repeats=5)


# -- one run ---------------------------------------------------------------

#: The bound 'auto' measured, by starting positions: every run of a sweep
#: starts from the same atoms, so each system is probed once.
_AUTO_BOUNDS = {}


def auto_force_noise(atoms):
    """The guard's bound 'auto' measures for the bare asap3 potential at
    these positions."""
    key = atoms.positions.tobytes()
    if key not in _AUTO_BOUNDS:
        calc = atoms.calc
        probe = atoms.copy()
        probe.calc = calc.inner if isinstance(calc, ResultCache) else calc
        _AUTO_BOUNDS[key] = purity.measured_force_noise(probe)
    return _AUTO_BOUNDS[key]


def make_dynamics(method, atoms, dt):
    if method.scheme is None:
        return VelocityVerlet(atoms, dt)
    # 'guarded' with the bound 'auto' measures for asap3; said explicitly
    # because the cluster's asap3 potential sits behind ResultCache.  The
    # energy check is off: the sweep starts at steps whose error is meant
    # to be measured, not stopped (and VelocityVerlet has no such check).
    return ReversibleVerlet(atoms, dt, scheme=method.scheme,
                            order=method.order, force_purity='guarded',
                            energy_check=0,
                            force_noise=auto_force_noise(atoms))


def measure(system, template, method, k):
    """Run ``method`` with ``k`` steps per sampling interval; the sampling
    observer's own time is subtracted (a 'position' sample costs a force
    call an unobserved run would not make)."""
    atoms = template.copy()
    atoms.calc = system.calc()
    dt_fs = system.interval_fs / k
    samples = round(system.simulated_fs / system.interval_fs)
    n_steps = k * samples
    dyn = make_dynamics(method, atoms, dt_fs * units.fs)
    energies = []
    spent = [0.0, 0.0]
    widest = [0.0]

    def sample():
        w, c = time.perf_counter(), time.process_time()
        energies.append(atoms.get_total_energy())
        if system.free:
            widest[0] = max(widest[0], float(pdist(atoms.positions).max()))
        spent[0] += time.perf_counter() - w
        spent[1] += time.process_time() - c

    dyn.attach(sample, interval=k)
    w, c = time.perf_counter(), time.process_time()
    failure = None
    try:
        dyn.run(n_steps)
    except Exception as error:  # an unstable step: record it, go finer
        failure = f'{type(error).__name__}'
    wall = time.perf_counter() - w - spent[0]
    cpu = time.process_time() - c - spent[1]
    point = {'k': k, 'dt_fs': dt_fs, 'steps': n_steps, 'wall_s': wall,
             'cpu_s': cpu, 'sampling_wall_s': spent[0]}
    point['widest_distance'] = widest[0] if system.free else None
    e = np.array(energies)
    if failure is None and len(e) == samples + 1 and np.isfinite(e).all():
        point['max_error'] = float((np.abs(e - e[0]) / abs(e[0])).max())
    else:
        point['max_error'] = None
        point['failure'] = failure or 'non-finite energy'
    return point


def timed(system, template, method, k, settings):
    """One point of a sweep; short runs are repeated for a steadier time."""
    runs = [measure(system, template, method, k)]
    while (len(runs) < settings.repeats
           and sum(r['wall_s'] + r['sampling_wall_s'] for r in runs)
           < settings.min_timed_seconds):
        runs.append(measure(system, template, method, k))
    point = dict(runs[0])
    point['repeats'] = len(runs)
    point['wall_s'] = statistics.median(r['wall_s'] for r in runs)
    point['cpu_s'] = statistics.median(r['cpu_s'] for r in runs)
    point['sampling_wall_s'] = statistics.median(r['sampling_wall_s']
                                                 for r in runs)
    # The repeats follow the same trajectory bit for bit: guard that.
    point['repeats_agree'] = all(r['max_error'] == point['max_error']
                                 for r in runs)
    return point


def sweep(system, template, method, settings):
    start_fs = min(system.interval_fs,
                   system.start_fs_per_call * method.stages)
    k_start = system.interval_fs / start_fs
    points, stop = [], 'ladder end'
    for k in settings.ladder:
        if k < k_start:
            continue
        if points:
            last = points[-1]
            predicted = (last['wall_s'] + last['sampling_wall_s']) \
                * k / last['k']
            if predicted > settings.max_run_seconds:
                stop = 'time budget'
                break
        point = timed(system, template, method, k, settings)
        points.append(point)
        if point['max_error'] is None:
            continue
        if point['max_error'] <= STOP_FRACTION * TARGET:
            stop = 'below target'
            break
        earlier = [p['max_error'] for p in points if p['max_error']
                   and p['dt_fs'] >= FLOOR_STEP_RATIO * point['dt_fs']]
        later = [p['max_error'] for p in points if p['max_error']
                 and p['dt_fs'] < FLOOR_STEP_RATIO * point['dt_fs']]
        if (earlier and point['max_error'] < 1e-6
                and min(later) * FLOOR_GAIN > min(earlier)):
            stop = 'floor'
            break
    return {'method': method.label, 'scheme': method.scheme,
            'order': method.order, 'stages': method.stages,
            'stop': stop, 'points': points}


def time_to_target(points, key='wall_s'):
    """``(seconds, how)`` to reach TARGET, log-log interpolated at the
    first crossing: 'interpolated', 'at most' or 'not reached'."""
    valid = [p for p in points if p['max_error'] is not None]
    for i, p in enumerate(valid):
        if p['max_error'] <= TARGET:
            if i == 0:
                return p[key], 'at most'
            q = valid[i - 1]
            x0, x1 = math.log(q[key]), math.log(p[key])
            y0, y1 = math.log(q['max_error']), math.log(p['max_error'])
            f = (math.log(TARGET) - y0) / (y1 - y0)
            return math.exp(x0 + f * (x1 - x0)), 'interpolated'
    return None, 'not reached'


def summarise(sweeps):
    rows = []
    for s in sweeps:
        wall, how = time_to_target(s['points'], 'wall_s')
        cpu, _ = time_to_target(s['points'], 'cpu_s')
        errors = [p['max_error'] for p in s['points']
                  if p['max_error'] is not None]
        rows.append({'method': s['method'], 'stages': s['stages'],
                     'wall_s': wall, 'cpu_s': cpu, 'how': how,
                     'best_error': min(errors) if errors else None,
                     'stop': s['stop']})
    vv = rows[0]
    for row in rows:
        for key in ('wall_s', 'cpu_s'):
            row[f'{key}_ratio'] = (row[key] / vv[key]
                                   if row[key] and vv[key] else None)
    return rows


# -- section API -------------------------------------------------------------

def run(quick):
    settings = QUICK if quick else FULL
    out = {'target': TARGET, 'stop_fraction': STOP_FRACTION,
           'floor_gain': FLOOR_GAIN, 'floor_step_ratio': FLOOR_STEP_RATIO,
           'max_run_seconds': settings.max_run_seconds,
           'min_timed_seconds': settings.min_timed_seconds,
           'repeats': settings.repeats,
           'ladder': list(settings.ladder), 'systems': []}
    for system in systems(quick):
        template = system.build()
        probe = template.copy()
        probe.calc = system.calc()
        e0 = probe.get_total_energy()
        sweeps = []
        for method in methods(quick):
            print(f'  {system.key}: {method.label}', flush=True)
            sweeps.append(sweep(system, template, method, settings))
        result = {
            'key': system.key, 'label': system.label,
            'atoms': len(template), 'formula': template.get_chemical_formula(),
            'pbc': bool(template.pbc.any()),
            'temperature_K': (AR_TEMPERATURE_K if system.free
                              else CU_TEMPERATURE_K),
            'calculator': ('asap3.LennardJones' if system.free
                           else 'asap3.RGL'),
            'interval_fs': system.interval_fs,
            'simulated_fs': system.simulated_fs,
            'initial_energy_eV': e0,
            'sweeps': sweeps, 'summary': summarise(sweeps),
        }
        if system.free:
            result['cutoff'] = AR_CUTOFF
            result['widest_distance'] = max(
                p['widest_distance'] for s in sweeps for p in s['points'])
        out['systems'].append(result)
    return out
