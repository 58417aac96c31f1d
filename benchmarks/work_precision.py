"""Work against precision: run time to reach a given energy error.

For each integrator -- ASE's VelocityVerlet and ReversibleVerlet with both
schemes at orders 2 to 8 (and 10 in full mode) -- a sweep of time steps,
each run over the same simulated time, records the relative total-energy
error ``|E(t) - E(0)| / |E(0)|`` at the same simulated times (every time
step divides the sampling interval) and the time the run took without the
sampling.  A method's sweep starts at a coarse step and refines it until
the error is well below the target, stops improving, or the next run would
exceed a time budget.

Systems, both through asap3 (ReversibleVerlet in its 'guarded' force
purity, as 'auto' picks for asap3):

- a free argon icosahedron, Lennard-Jones with a cutoff larger than any
  distance in the cluster, so no pair ever crosses it; the potential sits
  behind ``ResultCache`` so that VelocityVerlet is not charged for asap3
  recomputing at unchanged positions (``cache_check``);
- periodic fcc copper with the RGL (Gupta) potential, whose cutoff function
  is smooth.  asap3's EMT is not used for the solid: its neighbour list
  truncates the logistic cutoff function where it is still about 3e-3, so
  the energy jumps whenever a 4th-neighbour pair crosses the list cutoff;
  ``emt_check`` measures the floor this puts on VelocityVerlet's error.

The guarded mode coarsens the momentum quantum, which puts a floor under
ReversibleVerlet's energy error; ``quantum_check`` measures it.
"""

from __future__ import annotations

import common  # noqa: F401  (first: pins BLAS threads before numpy)

import math
import statistics
import time
from dataclasses import dataclass, replace
from typing import Callable

import asap3
import numpy as np
from ase import units
from ase.build import bulk
from ase.cluster import Icosahedron
from ase.md.verlet import VelocityVerlet
from scipy.spatial.distance import pdist

from ase_reversible import ReversibleVerlet
from ase_reversible.core.compositions import composition_for

TITLE = 'Work against precision'

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

# Argon: Lennard-Jones parameters (eV, Å), lattice constant (Å).
AR_EPSILON, AR_SIGMA, AR_LATTICE = 0.0104, 3.4, 5.26
#: Larger than the cluster's diameter (22 Å for 147 atoms) with margin.
AR_CUTOFF = 40.0
AR_TEMPERATURE_K = 30.0
# Copper: RGL parameters of Cleri and Rosato, Phys. Rev. B 48, 22 (1993).
CU_RGL = dict(p=10.960, q=2.278, a=0.0855, xi=1.224, r0=2.556)
CU_LATTICE = 3.615  # sqrt(2) * r0, the potential's own lattice constant
CU_TEMPERATURE_K = 300.0


@dataclass(frozen=True)
class Method:
    label: str
    scheme: str | None  # None: ASE's VelocityVerlet
    order: int

    @property
    def stages(self) -> int:
        if self.scheme is None:
            return 1
        return composition_for(self.order).stages


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
    def build():
        atoms = Icosahedron('Ar', shells, latticeconstant=AR_LATTICE)
        atoms.center(vacuum=10.0)
        return common.thermalised(atoms, AR_TEMPERATURE_K, seed=0)
    return build


def raw_argon_lj():
    return asap3.LennardJones([18], [AR_EPSILON], [AR_SIGMA],
                              rCut=AR_CUTOFF, modified=True)


class ResultCache:
    """An asap3 potential behind a cache of its last results.

    asap3's LennardJones recomputes on every call for this free cluster,
    even at unchanged positions (``cache_check`` measures it), and ASE's
    VelocityVerlet asks for the forces three times per step: bare, it
    would pay three force computations per step where ReversibleVerlet,
    which keeps its own cache, pays one.  ASE's own cache
    (``Calculator.check_state``) is no fix: its comparisons cost more than
    the force call itself for this small cluster.  An exact comparison of
    the positions costs a few microseconds, the same for both integrators.
    """

    def __init__(self, inner):
        self.inner = inner
        self._mirror = None  # atoms carrying the inner calculator
        # Forces and energy are separate computations of the bare
        # potential, so each is computed only when asked for.
        self._forces_at = self._energy_at = None
        self._f_nc = self._energy = None

    def _move(self, atoms):
        if self._mirror is None or len(self._mirror) != len(atoms):
            self._mirror = atoms.copy()
            self._mirror.calc = self.inner
        self._mirror.positions = atoms.positions

    def get_forces(self, atoms):
        x_nc = atoms.positions
        if self._forces_at is None or not np.array_equal(x_nc,
                                                         self._forces_at):
            self._move(atoms)
            self._f_nc = self._mirror.get_forces()
            self._forces_at = x_nc.copy()
        return self._f_nc.copy()

    def get_potential_energy(self, atoms, force_consistent=False):
        x_nc = atoms.positions
        if self._energy_at is None or not np.array_equal(x_nc,
                                                         self._energy_at):
            self._move(atoms)
            self._energy = self._mirror.get_potential_energy()
            self._energy_at = x_nc.copy()
        return self._energy


def argon_lj():
    return ResultCache(raw_argon_lj())


def copper_crystal(repeat):
    def build():
        atoms = bulk('Cu', 'fcc', a=CU_LATTICE, cubic=True) * repeat
        return common.thermalised(atoms, CU_TEMPERATURE_K, seed=0)
    return build


def copper_rgl():
    return asap3.RGL(['Cu'], **CU_RGL)


def systems(quick):
    shells, simulated_ar = (3, 640.0) if quick else (4, 1536.0)
    repeat, simulated_cu = ((3, 3, 3), 96.0) if quick else ((4, 4, 4), 320.0)
    return [
        System('argon_cluster', 'free Ar cluster', argon_cluster(shells),
               argon_lj, interval_fs=64.0, simulated_fs=simulated_ar,
               start_fs_per_call=16.0, free=True),
        System('copper_crystal', 'periodic Cu crystal',
               copper_crystal(repeat), copper_rgl, interval_fs=16.0,
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
    #: Length of the runs of the sampling check.
    check_seconds: float


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
                 repeats=3, check_seconds=0.2)
FULL = Settings(_ladder(False), max_run_seconds=40.0, min_timed_seconds=0.3,
                repeats=5, check_seconds=1.5)


# -- one run ---------------------------------------------------------------

def make_dynamics(method, atoms, dt, **kwargs):
    if method.scheme is None:
        return VelocityVerlet(atoms, dt)
    # 'guarded' is what 'auto' picks for asap3; said explicitly because
    # the cluster's asap3 potential sits behind ResultCache.  The energy
    # check is off: the sweep starts at steps whose error is meant to be
    # measured, not stopped (and VelocityVerlet has no such check).
    kwargs.setdefault('energy_check', 0)
    return ReversibleVerlet(atoms, dt, scheme=method.scheme,
                            order=method.order, force_purity='guarded',
                            **kwargs)


def measure(system, template, method, k, observe=True, samples=None,
            **kwargs):
    """Run ``method`` with ``k`` steps per sampling interval.

    The sampling observer times itself; its wall and CPU time are
    subtracted from the run's, since for the 'position' scheme each energy
    sample costs a force call that an unobserved run would not make.
    """
    atoms = template.copy()
    atoms.calc = system.calc()
    dt_fs = system.interval_fs / k
    if samples is None:
        samples = round(system.simulated_fs / system.interval_fs)
    n_steps = k * samples
    dyn = make_dynamics(method, atoms, dt_fs * units.fs, **kwargs)
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

    if observe:
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
    if not observe:
        return point
    purity = getattr(dyn, 'force_purity', None)
    clean = getattr(purity, 'clean_recomputations', 0)
    # VelocityVerlet and kick-drift-kick compute the forces once before the
    # first step; drift-kick-drift starts with a drift.  A clean
    # recomputation of the guarded mode costs two calls.
    initial = 0 if method.scheme == 'position' else 1
    point['force_calls'] = initial + n_steps * method.stages + 2 * clean
    point['clean_recomputations'] = clean
    if hasattr(dyn, 'grid'):
        point['momentum_quantum'] = dyn.grid.momentum_quantum
    point['widest_distance'] = widest[0] if system.free else None
    e = np.array(energies)
    relative = np.abs(e - e[0]) / abs(e[0])
    if failure is None and len(e) == samples + 1 and np.isfinite(e).all():
        point['max_error'] = float(relative.max())
        point['rms_error'] = float(np.sqrt(np.mean(relative[1:] ** 2)))
    else:
        point['max_error'] = point['rms_error'] = None
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
    """Time to reach TARGET, interpolated log-log at the first crossing.

    Returns ``(seconds, how)``: how is 'interpolated', 'at most' (the
    coarsest step already reached it) or 'not reached'.
    """
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


# -- checks ------------------------------------------------------------------

def sampling_check(system, template, settings):
    """Subtracted sampling time against runs with no observer at all.

    Taken where sampling is dearest in the sweeps: the 'position' scheme
    at order 4 with the energy sampled after every step, one extra force
    call per 5.  The run is lengthened to about ``check_seconds``.
    """
    method = Method('position 4', 'position', 4)
    probe = measure(system, template, method, 1, samples=4)
    per_sample = max(probe['wall_s'] + probe['sampling_wall_s'], 1e-6) / 4
    samples = max(4, round(settings.check_seconds / per_sample))
    observed, unobserved = [], []
    for _ in range(3):  # interleaved, so drifts of the load hit both alike
        observed.append(measure(system, template, method, 1,
                                samples=samples))
        unobserved.append(measure(system, template, method, 1,
                                  samples=samples, observe=False))
    median = statistics.median
    return {'method': method.label, 'dt_fs': system.interval_fs,
            'steps': samples, 'repeats': len(observed),
            'sampling_wall_s': median(q['sampling_wall_s']
                                      for q in observed),
            'subtracted_wall_s': median(q['wall_s'] for q in observed),
            'unobserved_wall_s': median(q['wall_s'] for q in unobserved),
            'subtracted_cpu_s': median(q['cpu_s'] for q in observed),
            'unobserved_cpu_s': median(q['cpu_s'] for q in unobserved)}


def quantum_check(system, template, sweeps, factor=2.0**-10):
    """The error floor set by the guarded mode's momentum quantum.

    Reruns the most accurate point of the highest-order kick-drift-kick
    sweep, the one whose truncation error is most likely below the floor,
    with a momentum quantum ``factor`` times the default (more clean
    recomputations, still exactly reversible).
    """
    candidates = [s for s in sweeps if s['scheme'] == 'velocity']
    s = max(candidates, key=lambda s: s['order'])
    valid = [p for p in s['points'] if p['max_error'] is not None]
    if not valid:
        return None
    p = min(valid, key=lambda p: p['max_error'])
    method = Method(s['method'], s['scheme'], s['order'])
    fine = measure(system, template, method, p['k'],
                   momentum_quantum=p['momentum_quantum'] * factor)
    return {'method': s['method'], 'dt_fs': p['dt_fs'],
            'default_quantum': p['momentum_quantum'],
            'default_error': p['max_error'],
            'fine_quantum': fine['momentum_quantum'],
            'fine_error': fine['max_error'],
            'fine_clean_recomputations': fine['clean_recomputations'],
            'fine_force_calls': fine['force_calls'],
            'default_force_calls': p['force_calls']}


def cache_check(system, template, raw_calc, settings, calls=40, blocks=5):
    """What a repeated force request costs with the bare asap3 potential.

    Microseconds per ``get_forces`` call at unchanged positions against a
    call after moving one atom by 1e-9 Å (a real computation, never a
    neighbour-list rebuild): the fastest of ``blocks`` blocks of ``calls``
    calls, as a time slice lost to other load would swamp a block.  Where
    the system's calculator is a ResultCache, also VelocityVerlet's time
    per step with and without it, unobserved runs interleaved.
    """
    atoms = template.copy()
    atoms.calc = raw_calc()
    atoms.get_forces()
    x_nc = atoms.positions.copy()

    def repeated():
        for _ in range(calls):
            atoms.get_forces(md=True)

    def fresh():
        for i in range(calls):
            x_nc[0, 0] += 1e-9 if i % 2 == 0 else -1e-9
            atoms.positions = x_nc
            atoms.get_forces(md=True)

    def per_call(block):
        times = []
        for _ in range(blocks):
            w = time.perf_counter()
            block()
            times.append((time.perf_counter() - w) / calls)
        return min(times)

    out = {'repeated_call_us': per_call(repeated) * 1e6,
           'fresh_call_us': per_call(fresh) * 1e6}
    if system.calc is raw_calc:
        return out
    k = 8  # 8 fs for argon: stable, and the cost per step does not care
    probe = measure(system, template, VV, k, observe=False, samples=1)
    samples = max(1, round(settings.check_seconds
                           / max(probe['wall_s'], 1e-6)))
    bare = replace(system, calc=raw_calc)
    cached, uncached = [], []
    for _ in range(3):
        cached.append(measure(system, template, VV, k, observe=False,
                              samples=samples))
        uncached.append(measure(bare, template, VV, k, observe=False,
                                samples=samples))
    steps = k * samples
    out.update({
        'vv_steps': steps,
        'vv_cached_us_per_step': statistics.median(
            q['wall_s'] for q in cached) / steps * 1e6,
        'vv_bare_us_per_step': statistics.median(
            q['wall_s'] for q in uncached) / steps * 1e6})
    return out


def emt_cutoff(template):
    """Where asap3's EMT truncates its cutoff function, for ``template``.

    ASE's EMT with ``asap_cutoff=True`` reproduces asap3's neighbour-list
    cutoff, and exposes it: the logistic function's value there and the
    gap to the 4th-neighbour shell of the lattice.
    """
    from ase.calculators.emt import EMT
    atoms = template.copy()
    calc = EMT(asap_cutoff=True)
    atoms.calc = calc
    atoms.get_potential_energy()
    weight = 1.0 / (1.0 + math.exp(calc.acut * (calc.rc_list - calc.rc)))
    fourth = CU_LATTICE * math.sqrt(2.0)
    return {'list_cutoff': calc.rc_list, 'weight_at_cutoff': weight,
            'fourth_neighbour': fourth}


def emt_check(copper, template, dts_fs=(0.5, 0.125)):
    """VelocityVerlet's max error with asap3 EMT and with RGL, same runs."""
    rows = []
    for name, calc in (('asap3 EMT', asap3.EMT), ('asap3 RGL', copper_rgl)):
        system = replace(copper, calc=calc)
        for dt in dts_fs:
            p = measure(system, template, VV, round(copper.interval_fs / dt))
            rows.append({'calculator': name, 'dt_fs': p['dt_fs'],
                         'max_error': p['max_error'],
                         'rms_error': p['rms_error']})
    return rows


# -- section API -------------------------------------------------------------

def run(quick, figures):
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
            'sampling_check': sampling_check(system, template, settings),
            'quantum_check': quantum_check(system, template, sweeps),
        }
        result['cache_check'] = cache_check(
            system, template, raw_argon_lj if system.free else copper_rgl,
            settings)
        if system.free:
            result['cutoff'] = AR_CUTOFF
            result['widest_distance'] = max(
                p['widest_distance'] for s in sweeps for p in s['points'])
        else:
            print('  copper_crystal: EMT check', flush=True)
            result['emt_check'] = emt_check(system, template)
            result['emt_cutoff'] = emt_cutoff(template)
        result['plot'] = plot(result, figures)
        out['systems'].append(result)
    return out


STYLE = {2: 'C0', 4: 'C1', 6: 'C2', 8: 'C3', 10: 'C4'}


def _style(sweep):
    if sweep['scheme'] is None:
        # On top: velocity 2 has the same errors and would hide it.
        return dict(color='black', linestyle='-', marker='o', zorder=3,
                    linewidth=1, markersize=3)
    return dict(color=STYLE[sweep['order']], zorder=2,
                linestyle='-' if sweep['scheme'] == 'velocity' else '--',
                marker='s' if sweep['scheme'] == 'velocity' else '^',
                markerfacecolor='none' if sweep['scheme'] == 'position'
                else None)


def plot(result, figures):
    plt = common.pyplot()
    fig, (ax_work, ax_dt) = plt.subplots(1, 2, figsize=(12, 5))
    for s in result['sweeps']:
        pts = [p for p in s['points'] if p['max_error'] is not None]
        if not pts:
            continue
        style = _style(s)
        ax_work.plot([p['wall_s'] for p in pts], [p['max_error'] for p in pts],
                     label=s['method'], **{'markersize': 4, **style})
        ax_dt.plot([p['dt_fs'] for p in pts], [p['max_error'] for p in pts],
                   label=s['method'], **{'markersize': 4, **style})
    for ax in (ax_work, ax_dt):
        ax.set_xscale('log')
        ax.set_yscale('log')
        ax.axhline(TARGET, color='grey', linewidth=0.8, linestyle=':')
        ax.grid(True, which='major', alpha=0.3)
    ax_work.set_xlabel('wall time of the run without sampling (s)')
    ax_dt.set_xlabel('time step (fs)')
    for ax in (ax_work, ax_dt):
        ax.set_ylabel('max relative total-energy error')
    ax_work.set_title(f"{result['label']}: {result['formula']}, "
                      f"{result['simulated_fs']:g} fs")
    ax_dt.set_title('error against time step')
    ax_dt.legend(fontsize=7, ncol=2)
    fig.subplots_adjust(left=0.07, right=0.98, bottom=0.11, top=0.93,
                        wspace=0.22)
    name = f"work_precision_{result['key']}.png"
    fig.savefig(figures / name, dpi=110)
    plt.close(fig)
    return name


# -- Markdown ----------------------------------------------------------------

def _g(x, digits=3):
    return '–' if x is None else f'{x:.{digits}g}'


def _e(x):
    return '–' if x is None else f'{x:.2e}'


def _time_cell(row, key):
    if row[key] is None:
        return 'not reached'
    prefix = '≤ ' if row['how'] == 'at most' else ''
    return f'{prefix}{row[key]:.3g} s'


def render(results):
    target = results['target']
    lines = [
        'Relative total-energy error `|E(t) - E(0)| / |E(0)|` against the '
        'time a run takes, over a sweep of time steps, for ASE\'s '
        '`VelocityVerlet` and `ReversibleVerlet` with both schemes and '
        'each order.  Every run covers the same simulated time and samples '
        'the energy at the same simulated times (each time step divides the '
        'sampling interval, which is also the largest step); the max and '
        'RMS are over the samples after t = 0.  E(0) is each run\'s own '
        'initial energy (ReversibleVerlet snaps the state to its grid '
        'first).  ReversibleVerlet runs in its `guarded` force-purity mode, '
        'the one `auto` picks for asap3 calculators.',
        '',
        '**Timing.**  Wall time (`time.perf_counter`) of `dyn.run(n)`, '
        'minus the time spent in the sampling observer, which times itself: '
        'for the `position` scheme each sample costs a force call that an '
        'unobserved run does not make, so charging it would be unfair.  '
        'The check below compares the subtracted time with runs that have '
        'no observer at all.  CPU time (`time.process_time`, sampling '
        'subtracted the same way) is reported too, as it is less sensitive '
        'to other load on a shared machine.  A run shorter than '
        f'{results["min_timed_seconds"]:g} s is repeated, up to '
        f'{results["repeats"]} runs with fresh atoms and calculator (the '
        'same trajectory bit for bit: the errors are checked equal), and '
        'timed by the median.  '
        '**Force calls** are counted from the schedule (one per stage per '
        'step, plus the initial call of kick-drift-kick schemes and two '
        'per clean recomputation of the guarded force mode), excluding the '
        'sampling.',
        '',
        '**Sweeps.**  Each method starts at a coarse time step ('
        'proportional to its number of stages, capped at the sampling '
        'interval) and refines it through '
        + ', '.join(map(str, results['ladder'][:7]))
        + ', ... steps per sampling interval until its max error is below '
        f'{results["stop_fraction"]:g} × {target:g}, or its best error has '
        f'not improved by {results["floor_gain"]:g}× while the step shrank '
        f'{results["floor_step_ratio"]:g}× (a floor), or the next run '
        f'would take more than {results["max_run_seconds"]:g} s.  The time '
        f'to reach {target:g} is interpolated log-log between the last '
        f'point above and the first point at or below {target:g}.',
        '',
    ]
    for r in results['systems']:
        lines += _render_system(r, target)
    return '\n'.join(lines)


def _render_system(r, target):
    e0_atom = r['initial_energy_eV'] / r['atoms']
    lines = [f"### {r['label'][0].upper() + r['label'][1:]}", '']
    if r['pbc']:
        desc = (f"{r['formula']} ({r['atoms']} atoms), periodic fcc, "
                f"`{r['calculator']}` (Cleri–Rosato parameters), "
                f"thermalised at {r['temperature_K']:g} K from the perfect "
                f"lattice; E(0) = {e0_atom:.4g} eV/atom.")
    else:
        desc = (f"{r['formula']} icosahedron ({r['atoms']} atoms) in "
                f"vacuum, `{r['calculator']}` (behind `ResultCache`, see "
                f"below) with cutoff "
                f"{r['cutoff']:g} Å; the widest interatomic distance in "
                f"any sample was {r['widest_distance']:.1f} Å, far inside "
                f"the cutoff, so no pair crosses it.  Thermalised at "
                f"{r['temperature_K']:g} K; E(0) = {e0_atom:.4g} eV/atom.")
    lines += [desc + f"  Simulated time {r['simulated_fs']:g} fs, energy "
              f"sampled every {r['interval_fs']:g} fs.", '']
    lines += [f"![Work-precision, {r['label']}](benchmarks/{r['plot']})", '']

    rows = r['summary']
    table = []
    for row in rows:
        table.append([row['method'], row['stages'],
                      _time_cell(row, 'wall_s'), _g(row['wall_s_ratio']),
                      _time_cell(row, 'cpu_s'), _g(row['cpu_s_ratio']),
                      _e(row['best_error']), row['stop']])
    lines += [f'Time to reach a max relative error of {target:g} (ratio: '
              'to VelocityVerlet; best: smallest max error in the sweep; '
              'stop: why the sweep ended):', '',
              common.markdown_table(
                  ['method', 'force calls / step', 'wall to target',
                   'wall ratio', 'CPU to target', 'CPU ratio', 'best error',
                   'stop'], table), '']
    lines += _observations(r, target)
    lines += _checks(r)
    lines += ['<details><summary>Every run</summary>', '']
    table = []
    for s in r['sweeps']:
        for p in s['points']:
            table.append([s['method'], f"{p['dt_fs']:.4g}", p['steps'],
                          p['force_calls'], p['repeats'],
                          f"{p['wall_s']:.3g}",
                          f"{p['cpu_s']:.3g}",
                          p.get('failure') or _e(p['max_error']),
                          _e(p['rms_error'])])
    lines += [common.markdown_table(
        ['method', 'dt (fs)', 'steps', 'force calls', 'runs', 'wall (s)',
         'CPU (s)',
         'max error', 'RMS error'], table), '', '</details>', '']
    return lines


def _observations(r, target):
    rows = r['summary']
    vv = rows[0]
    reached = [row for row in rows[1:] if row['wall_s'] is not None]
    out = []
    if vv['wall_s'] is None:
        out.append(f'- VelocityVerlet did not reach {target:g} within the '
                   f"sweep (best {_e(vv['best_error'])}).")
    else:
        out.append(f"- VelocityVerlet needs {vv['wall_s']:.3g} s "
                   f"({vv['cpu_s']:.3g} s CPU) to reach {target:g}.")
    if reached:
        best = min(reached, key=lambda row: row['wall_s'])
        out.append(f"- Fastest to {target:g}: {best['method']}, "
                   f"{best['wall_s']:.3g} s"
                   + (f", {1 / best['wall_s_ratio']:.3g}× faster than "
                      'VelocityVerlet' if best['wall_s_ratio'] else '')
                   + '.')
    goal = [row for row in rows if row['method'].split()[-1] in ('4', '6')
            and row['wall_s_ratio'] is not None]
    if vv['wall_s'] is not None:
        winners = [row for row in goal if row['wall_s_ratio'] < 1]
        if winners:
            out.append('- Goal (order 4 or 6 reaches the target in less wall '
                       'time than VelocityVerlet): **met** by '
                       + ', '.join(f"{row['method']} "
                                   f"({row['wall_s_ratio']:.2g}× VV's time)"
                                   for row in winners) + '.')
        else:
            out.append('- Goal (order 4 or 6 reaches the target in less wall '
                       'time than VelocityVerlet): **not met**.')
    missing = [row for row in rows[1:] if row['wall_s'] is None]
    for row in missing:
        out.append(f"- {row['method']} never reached {target:g} (best "
                   f"{_e(row['best_error'])}, sweep stopped: {row['stop']}).")
    bound = [row for row in rows if row['how'] == 'at most']
    if bound:
        out.append('- Already below the target at the coarsest step tried, '
                   'so the time is an upper bound: '
                   + ', '.join(row['method'] for row in bound) + '.')
    disagree = [f"{s['method']} at {p['dt_fs']:.4g} fs" for s in r['sweeps']
                for p in s['points'] if not p['repeats_agree']]
    if disagree:
        out.append('- Repeated runs gave different errors (not the same '
                   'trajectory): ' + ', '.join(disagree) + '.')
    order2 = [row for row in rows[1:]
              if row['method'].endswith(' 2') and row['wall_s_ratio']]
    if order2:
        out.append('- At order 2, ReversibleVerlet needs '
                   + ' and '.join(f"{row['wall_s_ratio']:.2g}× "
                                  f"({row['cpu_s_ratio']:.2g}× CPU)"
                                  for row in order2)
                   + " VelocityVerlet's time to the target ("
                   + ', '.join(row['method'] for row in order2) + ').')
    same = _same_step_errors(r['sweeps'], 'velocity 2')
    if same:
        out.append(f"- At equal time steps ({same[0]} of them), velocity 2's "
                   f"max errors are within {same[1]:.2g}% of "
                   "VelocityVerlet's: the same integrator up to rounding, "
                   'so its time ratio is the cost of the fixed-point step.')
    rev = [row for row in rows[1:] if row['best_error'] is not None]
    if rev:
        floor = min(row['best_error'] for row in rev)
        out.append(f"- Smallest max error reached by any ReversibleVerlet "
                   f"run: {floor:.2e}; by VelocityVerlet: "
                   f"{_e(vv['best_error'])}.")
    return out + ['']


def _same_step_errors(sweeps, label):
    """(number of shared time steps, largest relative difference in %)."""
    by_label = {s['method']: s for s in sweeps}
    if VV.label not in by_label or label not in by_label:
        return None
    vv = {p['k']: p['max_error'] for p in by_label[VV.label]['points']
          if p['max_error']}
    diffs = [abs(p['max_error'] / vv[p['k']] - 1) * 100
             for p in by_label[label]['points']
             if p['max_error'] and p['k'] in vv]
    return (len(diffs), max(diffs)) if diffs else None


def _checks(r):
    lines = []
    c = r.get('sampling_check')
    if c:
        lines += [
            f"**Sampling check.**  {c['method']} at dt = {c['dt_fs']:.4g} fs "
            f"with the energy sampled after every step ({c['steps']} steps, "
            f"the largest sampling share in the sweeps), median of "
            f"{c['repeats']} interleaved pairs of runs: the observer took "
            f"{c['sampling_wall_s']:.3g} s; the run time with it subtracted "
            f"was {c['subtracted_wall_s']:.3g} s wall / "
            f"{c['subtracted_cpu_s']:.3g} s CPU against "
            f"{c['unobserved_wall_s']:.3g} s / {c['unobserved_cpu_s']:.3g} s "
            f"for runs with no observer "
            f"({c['subtracted_wall_s'] / c['unobserved_wall_s'] - 1:+.1%} / "
            f"{c['subtracted_cpu_s'] / c['unobserved_cpu_s'] - 1:+.1%}).", '']
    cc = r.get('cache_check')
    if cc:
        text = (f"**Cached results.**  The bare `{r['calculator']}`: a "
                f"repeated `get_forces` at unchanged positions takes "
                f"{cc['repeated_call_us']:.3g} µs, a real computation "
                f"{cc['fresh_call_us']:.3g} µs.")
        if 'vv_bare_us_per_step' in cc:
            text += (f"  VelocityVerlet, which asks for the forces three "
                     f"times per step, takes {cc['vv_bare_us_per_step']:.3g}"
                     f" µs per step with the bare potential and "
                     f"{cc['vv_cached_us_per_step']:.3g} µs behind "
                     f"`ResultCache`, a cache of the last results keyed by "
                     f"the exact positions, used for every run of this "
                     f"section (ReversibleVerlet keeps its own cache and "
                     f"asks once per stage).")
        lines += [text, '']
    q = r.get('quantum_check')
    if q:
        lines += [
            f"**Momentum-quantum check.**  The most accurate "
            f"ReversibleVerlet run ({q['method']}, dt = {q['dt_fs']:.4g} fs)"
            f" used the default momentum quantum {q['default_quantum']:.3g} "
            f"(raised by the guarded force mode so that clean "
            f"recomputations stay rare) and reached {q['default_error']:.2e}"
            f"; with a quantum of {q['fine_quantum']:.3g} it reaches "
            f"{_e(q['fine_error'])} ({q['fine_clean_recomputations']} clean "
            f"recomputations, {q['fine_force_calls']} force calls instead "
            f"of {q['default_force_calls']}): "
            + ('the default quantum, not the integrator, sets this floor.'
               if q['fine_error'] is not None
               and q['fine_error'] < q['default_error'] / 4 else
               'this error is the integrator\'s, not the quantum\'s.'), '']
    emt = r.get('emt_check')
    cut = r.get('emt_cutoff')
    if emt:
        gap = cut['fourth_neighbour'] - cut['list_cutoff']
        table = [[row['calculator'], f"{row['dt_fs']:.4g}",
                  _e(row['max_error']), _e(row['rms_error'])]
                 for row in emt]
        gains = []
        for name in dict.fromkeys(row['calculator'] for row in emt):
            coarse, fine = [row for row in emt if row['calculator'] == name]
            if coarse['max_error'] and fine['max_error']:
                gain = coarse['max_error'] / fine['max_error']
                gains.append(f'{name} {gain:.3g}×')
            else:
                gains.append(f'{name} –')
            ratio = coarse['dt_fs'] / fine['dt_fs']
        lines += [
            '**Why not EMT.**  VelocityVerlet on the same crystal with '
            "asap3's EMT and with RGL at two time steps.  For a smooth "
            f'potential, dividing the step by {ratio:g} divides the max '
            f'error by {ratio ** 2:g}; measured: ' + ', '.join(gains)
            + f".  asap3's EMT cuts its neighbour list at "
            f"{cut['list_cutoff']:.3f} Å, where its logistic cutoff "
            f"function is still {cut['weight_at_cutoff']:.2g} (ASE's EMT "
            "with `asap_cutoff=True`, which mirrors it, tells): the energy "
            'jumps whenever a pair crosses that distance, and the 4th '
            f"neighbours sit only {gap:.2f} Å outside it.", '',
            common.markdown_table(['calculator', 'dt (fs)', 'max error',
                                   'RMS error'], table), '']
    return lines
