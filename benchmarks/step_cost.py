"""Cost per MD step of ReversibleVerlet against ASE's VelocityVerlet.

Usage::

    python benchmarks/step_cost.py           # full run, up to ~15 minutes
    python benchmarks/step_cost.py --quick   # small systems only, < 2 minutes

Writes ``docs/performance.md`` (the whole file, regenerated on every run) and
the raw timings to ``docs/step_cost.json``.

Method.  For each calculator and system, every contestant gets its own copy
of the same thermalised atoms with its own fresh calculator.  After a short
warm-up, the contestants run blocks of the same number of steps in rounds;
the order rotates from round to round, so slow drifts of the machine (clock
boosts, other load) hit all contestants alike.  A contestant's per-step time
is the median over rounds of block time / steps; ratios are ratios of these
medians.  The floor is the calculator's own force call: one atom is moved by
a tiny amount, so the calculator redoes the whole calculation but never
rebuilds its neighbour list.
"""

from __future__ import annotations

import os

# Single-threaded BLAS, set before numpy is imported.  Some numpy calls on
# the MD path go to OpenBLAS threads (np.vdot in Atoms.get_kinetic_energy,
# which MDLogger calls every step); on a busy machine every hand-off waits
# for a scheduler time slice, milliseconds that would swamp the per-step
# costs measured here.  Set the variables yourself to override.
BLAS_THREAD_VARIABLES = ('OPENBLAS_NUM_THREADS', 'OMP_NUM_THREADS',
                         'MKL_NUM_THREADS')
#: The caller's environment: `nproc` honours OMP_NUM_THREADS, so the machine
#: description must not see the value set here.
CALLER_ENVIRONMENT = dict(os.environ)
for _name in BLAS_THREAD_VARIABLES:
    os.environ.setdefault(_name, '1')

# The remaining imports follow the thread settings on purpose.
import argparse
import io
import json
import platform
import statistics
import subprocess
import sys
import time
import warnings
from dataclasses import asdict, dataclass
from datetime import datetime
from pathlib import Path
from typing import Callable

import asap3
import ase
import numpy as np
from ase import units
from ase.build import bulk
from ase.calculators.emt import EMT
from ase.calculators.lj import LennardJones
from ase.cluster import Icosahedron
from ase.md.logger import MDLogger
from ase.md.velocitydistribution import MaxwellBoltzmannDistribution
from ase.md.verlet import VelocityVerlet

import ase_reversible
from ase_reversible import ReversibleVerlet

DOCS = Path(__file__).resolve().parent.parent / 'docs'
TIMESTEP_FS = 5.0
TIMESTEP = TIMESTEP_FS * units.fs
WARMUP_STEPS = 5
#: Move of one coordinate (Å) that makes the calculator recompute: far below
#: any neighbour-list skin, so the floor never includes a list rebuild.
FLOOR_NUDGE = 1e-6

# Argon Lennard-Jones parameters (eV, Å) and lattice constant (Å).
AR_EPSILON, AR_SIGMA, AR_CUTOFF, AR_LATTICE = 0.0104, 3.4, 8.5, 5.26
AR_TEMPERATURE_K, CU_TEMPERATURE_K = 60.0, 300.0


@dataclass(frozen=True)
class Settings:
    label: str            # 'full' or 'quick'
    rounds: int
    block_seconds: float  # target wall time of one block
    min_steps: int        # per block, however slow the case
    max_steps: int


FULL = Settings('full', rounds=7, block_seconds=0.8, min_steps=5,
                max_steps=5000)
QUICK = Settings('quick', rounds=3, block_seconds=0.2, min_steps=3,
                 max_steps=1000)
#: Reversible velocity counts as "slower than VelocityVerlet" above this ratio.
SLOWER_THRESHOLD = 1.05


# -- systems and calculators -----------------------------------------------

def thermalised(atoms, temperature_K):
    # Deprecated in ASE 3.29, but a thin wrapper of thermalize_momenta,
    # which older ASE versions lack: same momenta, so keep it and its
    # warning quiet.
    with warnings.catch_warnings():
        warnings.simplefilter('ignore', DeprecationWarning)
        MaxwellBoltzmannDistribution(atoms, temperature_K=temperature_K,
                                     rng=np.random.default_rng(0),
                                     force_temp=True)
    return atoms


def argon_crystal(repeat):
    atoms = bulk('Ar', 'fcc', a=AR_LATTICE, cubic=True) * repeat
    return thermalised(atoms, AR_TEMPERATURE_K)


def argon_icosahedron():
    atoms = Icosahedron('Ar', 4, latticeconstant=AR_LATTICE)  # 147 atoms
    atoms.center(vacuum=10.0)
    return thermalised(atoms, AR_TEMPERATURE_K)


def copper_crystal(repeat):
    atoms = bulk('Cu', 'fcc', cubic=True) * repeat
    return thermalised(atoms, CU_TEMPERATURE_K)


def ase_lj():
    return LennardJones(sigma=AR_SIGMA, epsilon=AR_EPSILON, rc=AR_CUTOFF)


def asap_lj():
    return asap3.LennardJones([18], [AR_EPSILON], [AR_SIGMA],
                              rCut=AR_CUTOFF, modified=True)


@dataclass(frozen=True)
class Case:
    calculator: str
    system: str
    build: Callable[[], ase.Atoms]  # fresh thermalised atoms, no calculator
    make_calc: Callable[[], object]  # a fresh calculator


def step_cost_cases(quick):
    """Cases of the main table; quick mode keeps the smallest sizes."""
    # 4 atoms per cubic cell: (3, 3, 4) gives 144, 5**3 * 4 = 500, etc.
    ase_sizes = [(3, 3, 4)] if quick else [(3, 3, 4), (5, 5, 5)]
    asap_sizes = [(5, 5, 5)] if quick else [(5, 5, 5), (10, 10, 10),
                                             (20, 20, 20)]
    cases = []
    for r in ase_sizes:
        cases.append(Case('ASE LennardJones', 'Ar fcc crystal',
                          lambda r=r: argon_crystal(r), ase_lj))
    cases.append(Case('ASE LennardJones', 'Ar icosahedron (cluster)',
                      argon_icosahedron, ase_lj))
    for r in ase_sizes:
        cases.append(Case('ASE EMT', 'Cu fcc crystal',
                          lambda r=r: copper_crystal(r), EMT))
    for r in asap_sizes:
        cases.append(Case('asap3 LennardJones', 'Ar fcc crystal',
                          lambda r=r: argon_crystal(r), asap_lj))
    for r in asap_sizes:
        cases.append(Case('asap3 EMT', 'Cu fcc crystal',
                          lambda r=r: copper_crystal(r), asap3.EMT))
    return cases


def logging_cases(quick):
    """One ASE LJ and one mid-size asap3 EMT case for the logger table."""
    asap_repeat = (5, 5, 5) if quick else (10, 10, 10)
    return [Case('ASE LennardJones', 'Ar fcc crystal',
                 lambda: argon_crystal((3, 3, 4)), ase_lj),
            Case('asap3 EMT', 'Cu fcc crystal',
                 lambda: copper_crystal(asap_repeat), asap3.EMT)]


# -- contestants -----------------------------------------------------------

class ForceCallOnly:
    """The floor: one full force calculation per "step" and nothing else."""

    def __init__(self, atoms):
        self.atoms = atoms
        self._sign = 1.0

    def run(self, steps):
        x_nc = self.atoms.arrays['positions']
        for _ in range(steps):
            # Alternate the sign so the atom stays put on average.
            x_nc[0, 0] += self._sign * FLOOR_NUDGE
            self._sign = -self._sign
            self.atoms.get_forces()


INTEGRATORS = {
    'force': ForceCallOnly,
    'vv': lambda atoms: VelocityVerlet(atoms, TIMESTEP),
    'rv_velocity': lambda atoms: ReversibleVerlet(atoms, TIMESTEP,
                                                  scheme='velocity'),
    'rv_position': lambda atoms: ReversibleVerlet(atoms, TIMESTEP,
                                                  scheme='position'),
    'rv_trust': lambda atoms: ReversibleVerlet(atoms, TIMESTEP,
                                               scheme='velocity',
                                               force_purity='trust'),
}


@dataclass
class Contestant:
    name: str
    runner: object  # anything with run(steps)

    @property
    def purity(self):
        """The ReversibleVerlet force provider, or None."""
        return getattr(self.runner, 'force_purity', None)

    def clean_recomputations(self):
        return getattr(self.purity, 'clean_recomputations', None)


def make_contestants(case, names, with_logger=False):
    """Each contestant on its own copy of the same atoms and calculator."""
    template = case.build()
    contestants = []
    for name in names:
        atoms = template.copy()
        atoms.calc = case.make_calc()
        runner = INTEGRATORS[name](atoms)
        if with_logger and name != 'force':
            runner.attach(MDLogger(runner, atoms, io.StringIO()), interval=1)
        contestants.append(Contestant(name, runner))
    return contestants, len(template)


# -- timing ----------------------------------------------------------------

def choose_steps(reference, settings):
    """Steps per block so that the reference takes ~block_seconds."""
    steps = 1
    # Double until the sample is long enough for perf_counter to resolve it.
    while True:
        t0 = time.perf_counter()
        reference.runner.run(steps)
        elapsed = time.perf_counter() - t0
        if (elapsed > settings.block_seconds / 10
                or steps >= settings.max_steps):
            break
        steps *= 2
    per_step = elapsed / steps
    wanted = round(settings.block_seconds / per_step)
    return max(settings.min_steps, min(settings.max_steps, wanted))


def time_interleaved(contestants, steps, rounds):
    """Per-step times, order rotated each round.

    Returns ``(wall, cpu)``, each ``{name: [one value per round]}``.  Wall
    time (perf_counter) is the measurement; the process's CPU time is kept
    beside it because on a shared machine the difference shows how much
    other processes held the CPU.
    """
    wall = {c.name: [] for c in contestants}
    cpu = {c.name: [] for c in contestants}
    for r in range(rounds):
        shift = r % len(contestants)
        for c in contestants[shift:] + contestants[:shift]:
            w0, c0 = time.perf_counter(), time.process_time()
            c.runner.run(steps)
            wall[c.name].append((time.perf_counter() - w0) / steps)
            cpu[c.name].append((time.process_time() - c0) / steps)
    return wall, cpu


def time_cached_queries(atoms, calls, rounds=3):
    """Cost of asking the calculator again at unchanged positions.

    VelocityVerlet asks for the forces again at the start of each step and
    after it (ASE's _refresh_properties), and a logger asks for the energy
    after the forces; both are free only if the calculator returns cached
    results.  Returns median per-call seconds of ``get_forces()`` repeated,
    and of ``get_potential_energy()`` right after a force calculation.
    """
    forces_again, energy_after = [], []
    x_nc = atoms.arrays['positions']
    for _ in range(rounds):
        atoms.get_forces(md=True)
        t0 = time.perf_counter()
        for _ in range(calls):
            atoms.get_forces(md=True)
        forces_again.append((time.perf_counter() - t0) / calls)
        elapsed = 0.0
        for i in range(calls):
            x_nc[0, 0] += FLOOR_NUDGE if i % 2 == 0 else -FLOOR_NUDGE
            atoms.get_forces(md=True)
            t0 = time.perf_counter()
            atoms.get_potential_energy()
            elapsed += time.perf_counter() - t0
        energy_after.append(elapsed / calls)
    return statistics.median(forces_again), statistics.median(energy_after)


def _medians(samples):
    return {k: statistics.median(v) for k, v in samples.items()}


def benchmark(case, names, settings, with_logger=False):
    """Time one case; returns a JSON-ready dict of raw and median results."""
    contestants, n_atoms = make_contestants(case, names, with_logger)
    for c in contestants:
        c.runner.run(WARMUP_STEPS)
    by_name = {c.name: c for c in contestants}
    steps = choose_steps(by_name['vv'], settings)
    clean_before = {c.name: c.clean_recomputations() for c in contestants}
    wall, cpu = time_interleaved(contestants, steps, settings.rounds)
    force_calls = steps * settings.rounds  # one force evaluation per step
    clean = {}
    for c in contestants:
        if clean_before[c.name] is not None:
            clean[c.name] = {
                'recomputations': c.clean_recomputations()
                - clean_before[c.name],
                'force_calls': force_calls}
    # Few calls suffice: a cache hit and a recomputation differ 100-fold.
    forces_again, energy_after = time_cached_queries(
        by_name['force'].runner.atoms, min(steps, 20))
    result = {
        'calculator': case.calculator, 'system': case.system,
        'n_atoms': n_atoms, 'with_logger': with_logger,
        'steps_per_block': steps, 'rounds': settings.rounds,
        'per_step_seconds': wall,
        'per_step_cpu_seconds': cpu,
        'median_seconds': _medians(wall),
        'median_cpu_seconds': _medians(cpu),
        'spread': {k: (max(v) - min(v)) / statistics.median(v)
                   for k, v in wall.items()},
        'clean_recomputations': clean,
        'get_forces_again_seconds': forces_again,
        'energy_after_forces_seconds': energy_after,
        'force_purity': {c.name: c.purity.todict() for c in contestants
                         if c.purity is not None},
        'grids': {c.name: c.runner.grid.todict() for c in contestants
                  if hasattr(c.runner, 'grid')},
    }
    med = result['median_seconds']
    print(f'  {case.calculator:20s} {case.system:26s} N={n_atoms:6d} '
          f'S={steps:5d}  ' + '  '.join(f'{k}={v * 1e3:.3f}ms'
                                        for k, v in med.items()),
          flush=True)
    return result


# -- machine description ---------------------------------------------------

def _run(command):
    try:
        return subprocess.run(command, capture_output=True, text=True,
                              check=True, cwd=DOCS.parent,
                              env=CALLER_ENVIRONMENT).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return None


def cpu_model():
    try:
        with open('/proc/cpuinfo') as f:
            for line in f:
                if line.startswith('model name'):
                    return line.split(':', 1)[1].strip()
    except OSError:
        pass
    return None


def machine_info():
    uname = platform.uname()
    commit = _run(['git', 'rev-parse', '--short', 'HEAD'])
    dirty = _run(['git', 'status', '--porcelain', '--untracked-files=no'])
    return {
        'processor': platform.processor() or '(not reported)',
        'cpu_model': cpu_model(),
        'uname': f'{uname.system} {uname.release} {uname.machine}',
        'nproc': _run(['nproc']) or str(os.cpu_count()),
        'python': platform.python_version(),
        'numpy': np.__version__,
        'ase': ase.__version__,
        'asap3': asap3.__version__,
        'ase_reversible': ase_reversible.__version__,
        'git_commit': (commit + ('+local changes' if dirty else '')
                       if commit else None),
        'blas_threads': ', '.join(f'{name}={os.environ.get(name)}'
                                  for name in BLAS_THREAD_VARIABLES),
    }


# -- Markdown --------------------------------------------------------------

def ms(seconds):
    """Milliseconds with three significant digits, no exponent."""
    v = seconds * 1e3
    for limit, decimals in ((100, 0), (10, 1), (1, 2)):
        if abs(v) >= limit:
            return f'{v:.{decimals}f}'
    return f'{v:.3f}'


def with_ratio(result, name, reference='vv'):
    med = result['median_seconds']
    return f'{ms(med[name])} (×{med[name] / med[reference]:.2f})'


def overhead(result, name):
    """Time beyond the force call, in ms and in % of the force call."""
    med = result['median_seconds']
    extra = med[name] - med['force']
    return f'{ms(extra)} ({100 * extra / med["force"]:+.0f}%)'


def clean_fraction(result, name):
    entry = result['clean_recomputations'].get(name)
    if entry is None or result['force_purity'][name]['mode'] != 'guarded':
        return '—'
    k, n = entry['recomputations'], entry['force_calls']
    return f'{100 * k / n:.2g}% ({k}/{n})'


def step_cost_table(results):
    head = ('| calculator | system | N | purity (auto) | force call (ms) '
            '| VelocityVerlet (ms/step) | Reversible velocity (ms/step, ×VV) '
            '| Reversible position (ms/step, ×VV) '
            '| Reversible trust (ms/step, ×VV) '
            '| VV beyond force call (ms, %) '
            '| Reversible velocity beyond force call (ms, %) '
            '| clean recomputations, velocity / position | round spread '
            '| wall / CPU |')
    lines = [head, '|' + ' --- |' * head.count(' | ') + ' --- |']
    for r in results:
        med = r['median_seconds']
        spread = max(r['spread'].values())
        lines.append(
            f"| {r['calculator']} | {r['system']} | {r['n_atoms']} "
            f"| {r['force_purity']['rv_velocity']['mode']} "
            f"| {ms(med['force'])} | {ms(med['vv'])} "
            f"| {with_ratio(r, 'rv_velocity')} "
            f"| {with_ratio(r, 'rv_position')} "
            f"| {with_ratio(r, 'rv_trust')} "
            f"| {overhead(r, 'vv')} | {overhead(r, 'rv_velocity')} "
            f"| {clean_fraction(r, 'rv_velocity')} / "
            f"{clean_fraction(r, 'rv_position')} "
            f"| {100 * spread:.0f}% | {wall_over_cpu(r):.2f} |")
    return '\n'.join(lines)


def in_force_calls(result, key):
    return result[key] / result['median_seconds']['force']


def cache_table(results):
    head = ('| calculator | system | N | force call (ms) '
            '| get_forces() again (ms, in force calls) '
            '| get_potential_energy() after get_forces() '
            '(ms, in force calls) |')
    lines = [head, '|' + ' --- |' * head.count(' | ') + ' --- |']
    for r in results:
        cells = [f"{ms(r[key])} ({in_force_calls(r, key):.2f})"
                 for key in ('get_forces_again_seconds',
                             'energy_after_forces_seconds')]
        lines.append(
            f"| {r['calculator']} | {r['system']} | {r['n_atoms']} "
            f"| {ms(r['median_seconds']['force'])} | {cells[0]} "
            f"| {cells[1]} |")
    return '\n'.join(lines)


def wall_over_cpu(result):
    """Largest wall/CPU ratio of a case's medians: 1.00 on a quiet machine."""
    return max(result['median_seconds'][k] / result['median_cpu_seconds'][k]
               for k in result['median_seconds'])


def position_extra_calls(result):
    """Extra cost of 'position' over 'velocity', in force calls."""
    med = result['median_seconds']
    return (med['rv_position'] - med['rv_velocity']) / med['force']


def logging_table(results):
    head = ('| calculator | system | N | force call (ms) '
            '| VelocityVerlet + logger (ms/step) '
            '| Reversible velocity + logger (ms/step, ×VV) '
            '| Reversible position + logger (ms/step, ×VV) '
            '| position − velocity (ms/step, in force calls) '
            '| round spread | wall / CPU |')
    lines = [head, '|' + ' --- |' * head.count(' | ') + ' --- |']
    for r in results:
        med = r['median_seconds']
        extra = med['rv_position'] - med['rv_velocity']
        lines.append(
            f"| {r['calculator']} | {r['system']} | {r['n_atoms']} "
            f"| {ms(med['force'])} | {ms(med['vv'])} "
            f"| {with_ratio(r, 'rv_velocity')} "
            f"| {with_ratio(r, 'rv_position')} "
            f"| {ms(extra)} ({position_extra_calls(r):.2f}) "
            f"| {100 * max(r['spread'].values()):.0f}% "
            f"| {wall_over_cpu(r):.2f} |")
    return '\n'.join(lines)


def case_label(r):
    return f"{r['calculator']}, {r['system']}, N={r['n_atoms']}"


def summary(step_results, log_results):
    """Observations computed from this run's numbers."""
    def ratio(r, name):
        return r['median_seconds'][name] / r['median_seconds']['vv']

    out = []
    vel = sorted(step_results, key=lambda r: ratio(r, 'rv_velocity'))
    lo, hi = vel[0], vel[-1]
    out.append(f"- Reversible velocity / VelocityVerlet ranges from "
               f"×{ratio(lo, 'rv_velocity'):.2f} ({case_label(lo)}) to "
               f"×{ratio(hi, 'rv_velocity'):.2f} ({case_label(hi)}).")
    slower = [r for r in step_results
              if ratio(r, 'rv_velocity') > SLOWER_THRESHOLD]
    if slower:
        def excess(r):
            med = r['median_seconds']
            return (f"{case_label(r)}: "
                    f"+{100 * (ratio(r, 'rv_velocity') - 1):.0f}% "
                    f"(+{ms(med['rv_velocity'] - med['vv'])} ms/step)")
        items = '; '.join(excess(r) for r in slower)
        out.append(f'- Reversible velocity is more than '
                   f'{100 * (SLOWER_THRESHOLD - 1):.0f}% slower than '
                   f'VelocityVerlet in: {items}.')
    else:
        out.append(f'- Reversible velocity is nowhere more than '
                   f'{100 * (SLOWER_THRESHOLD - 1):.0f}% slower than '
                   f'VelocityVerlet.')
    purity_cost = [ratio(r, 'rv_velocity') / ratio(r, 'rv_trust')
                   for r in step_results]
    out.append(f"- Force purity handling (auto vs 'trust', velocity scheme) "
               f"costs ×{min(purity_cost):.2f} to ×{max(purity_cost):.2f}.")
    fractions = []
    for r in step_results:
        for name in ('rv_velocity', 'rv_position'):
            entry = r['clean_recomputations'].get(name)
            if entry and r['force_purity'][name]['mode'] == 'guarded':
                fractions.append(entry['recomputations']
                                 / entry['force_calls'])
    if fractions:
        out.append(f'- Guarded (asap3) force calls needing a clean '
                   f'recomputation: {100 * min(fractions):.2g}% to '
                   f'{100 * max(fractions):.2g}% (each costs two extra '
                   f'force calls).')
    def recomputes(key, threshold):
        hits = [r for r in step_results
                if in_force_calls(r, key) > threshold]
        return '; '.join(f'{case_label(r)}: {in_force_calls(r, key):.2f}'
                         for r in hits)

    items = recomputes('get_forces_again_seconds', 0.5)
    if items:
        out.append(f'- get_forces() at unchanged positions recomputes '
                   f'(cost in force calls) for {items}. VelocityVerlet, which '
                   f'asks for the forces again at the start and end of '
                   f'each step, pays for that; ReversibleVerlet keeps its '
                   f'own copy of the forces and does not.')
    items = recomputes('energy_after_forces_seconds', 0.1)
    if items:
        out.append(f'- get_potential_energy() right after get_forces() '
                   f'computes the energy again (cost in force calls) for '
                   f'{items}. A logger then pays that with every '
                   f'integrator, and the logged energy at the end of a '
                   f"'position' step is no extra work.")
    for r in log_results:
        out.append(f"- With a logger every step, 'position' costs "
                   f"{position_extra_calls(r):.2f} force calls per step more "
                   f"than 'velocity' ({case_label(r)}).")
    worst = max(step_results + log_results, key=wall_over_cpu)
    out.append(f'- Largest wall / CPU time ratio: {wall_over_cpu(worst):.2f} '
               f'({case_label(worst)}); well above 1 means other processes '
               f'took the CPU during the blocks and the wall times there are '
               f'noisier.')
    return '\n'.join(out)


def render_markdown(report):
    m, s = report['machine'], report['settings']
    quick = s['label'] == 'quick'
    title = '# Performance: cost per step' + (' (QUICK RUN)' if quick else '')
    quick_note = ('\n> **QUICK run**: small systems only, few rounds, short '
                  'blocks. Numbers are indicative; run without `--quick` '
                  'for the full table.\n' if quick else '')
    machine = '\n'.join(f'- {k}: {v}' for k, v in m.items() if v)
    load = report['load_average']
    machine += (f"\n- load average (1 min) at start / end: "
                f"{load['start']:.2f} / {load['end']:.2f} (this run adds "
                f"about 1; more means other processes shared the machine)")
    return f"""{title}

<!-- Generated by benchmarks/step_cost.py; edits are overwritten. -->

Produced by `{report['command']}` (run from the repository root) \
on {report['date']}; raw timings in `docs/step_cost.json`.
{quick_note}
Machine:

{machine}

## Method

Each contestant runs on its own copy of the same thermalised atoms with its
own fresh calculator: Ar at {AR_TEMPERATURE_K:g} K and Cu at \
{CU_TEMPERATURE_K:g} K (Maxwell-Boltzmann, seed 0), time step \
{TIMESTEP_FS:g} fs.
After {WARMUP_STEPS} warm-up steps each, the contestants run blocks of the
same number of steps, chosen per case so that a VelocityVerlet block takes
about {s['block_seconds']:g} s (at least {s['min_steps']} steps), in \
{s['rounds']} rounds with the order rotating each round.
Times are medians over rounds of block time / steps; ratios are ratios of
medians. "Round spread" is the largest (max − min) / median over the
contestants of a case: differences smaller than that are noise. "Wall /
CPU" is the largest ratio of a contestant's median wall time to its median
CPU time (`time.process_time`, also in the JSON): near 1.00 the process had
the CPU to itself. BLAS runs on one thread (see blas_threads above) so that
numpy's thread hand-offs do not add scheduler delays to the steps.

- **force call**: the calculator alone: one atom moved by {FLOOR_NUDGE:g} Å,
  then `atoms.get_forces()`, a full calculation that never rebuilds the
  neighbour list. The floor for any integrator with one force call per step.
- **VelocityVerlet**: `ase.md.verlet.VelocityVerlet`.
- **Reversible velocity / position**: `ReversibleVerlet(scheme=...)` with
  `force_purity='auto'` (exact reversal): 'sorted' for ASE calculators,
  'guarded' for asap3.
- **Reversible trust**: `ReversibleVerlet(scheme='velocity',
  force_purity='trust')`: the cost without any purity handling. *Not exact*
  for these calculators; a baseline only.
- **beyond force call**: median step time minus the force call's: the
  integrator's own work plus neighbour-list rebuilds (which the floor never
  does), in ms and in % of the force call.
- **clean recomputations**: for 'guarded', the share of force evaluations
  (one per step) whose kick was recomputed from a freshly built neighbour
  list, during the timed blocks, as count / force evaluations.

## Cost per step

{step_cost_table(report['step_cost'])}

## Scheme cost under logging

The same measurement with an `MDLogger` (writing to an `io.StringIO`)
attached every step. Kick-drift-kick ('velocity') ends a step with a force
calculation at the new positions, so the logger finds the energy in the
calculator's cache (if the calculator keeps it; see the diagnostic below);
drift-kick-drift ('position') ends a step between force calculations, so
the logger's energy is a calculation of its own at every logged step. The
second to last column gives that difference in units of the force call.

{logging_table(report['logging'])}

## Diagnostic: what the calculators cache

Asked again at unchanged positions (on the force-call contestant after the
rounds; median of three blocks): `get_forces()` repeated, as VelocityVerlet
does at the start and end of each step, and `get_potential_energy()` right
after `get_forces()`, as a logger does. A cache hit costs microseconds; a
recomputation costs up to a whole force call.

{cache_table(report['step_cost'])}

## Observations (computed from this run)

{summary(report['step_cost'], report['logging'])}

## Rerun

    python benchmarks/step_cost.py           # full, up to ~15 min
    python benchmarks/step_cost.py --quick   # small systems, < 2 min

Both regenerate this whole file and `docs/step_cost.json`.
"""


# -- main ------------------------------------------------------------------

def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--quick', action='store_true',
                        help='small systems, 3 rounds, short blocks')
    args = parser.parse_args(argv)
    settings = QUICK if args.quick else FULL
    started = time.perf_counter()
    load_start = os.getloadavg()[0]
    report = {
        'command': 'python benchmarks/step_cost.py'
                   + (' --quick' if args.quick else ''),
        'date': datetime.now().astimezone().isoformat(timespec='seconds'),
        'machine': machine_info(),
        'settings': {**asdict(settings), 'timestep_fs': TIMESTEP_FS,
                     'warmup_steps': WARMUP_STEPS,
                     'floor_nudge_angstrom': FLOOR_NUDGE},
    }
    print('Cost per step:', flush=True)
    report['step_cost'] = [
        benchmark(case, ['force', 'vv', 'rv_velocity', 'rv_position',
                         'rv_trust'], settings)
        for case in step_cost_cases(args.quick)]
    print('With a logger every step:', flush=True)
    report['logging'] = [
        benchmark(case, ['force', 'vv', 'rv_velocity', 'rv_position'],
                  settings, with_logger=True)
        for case in logging_cases(args.quick)]
    report['wall_seconds'] = time.perf_counter() - started
    report['load_average'] = {'start': load_start,
                              'end': os.getloadavg()[0]}

    DOCS.mkdir(exist_ok=True)
    (DOCS / 'step_cost.json').write_text(json.dumps(report, indent=1) + '\n')
    (DOCS / 'performance.md').write_text(render_markdown(report))
    print(f"Wrote {DOCS / 'performance.md'} and {DOCS / 'step_cost.json'} "
          f"in {report['wall_seconds']:.0f} s")


if __name__ == '__main__':
    sys.exit(main())
