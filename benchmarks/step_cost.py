"""Cost per MD step of ReversibleVerlet against ASE's VelocityVerlet.

A section of ``run_all.py``::

    python benchmarks/run_all.py --only step_cost           # ~8-12 minutes
    python benchmarks/run_all.py --quick --only step_cost   # < 40 s

Method.  For each calculator and system size, every contestant gets its own
copy of the same thermalised atoms with its own fresh calculator.  After a
short warm-up, the contestants run blocks of the same number of steps in
rounds; the order rotates from round to round, so slow drifts of the
machine (clock boosts, other load) hit all contestants alike.  A
contestant's per-step time is the median over rounds of block time / steps;
ratios are ratios of these medians.

Two floors stand for "the force call alone".  The nudge floor moves one atom
by a tiny amount, so the calculator redoes the whole calculation but never
rebuilds its neighbour list: it understates what MD costs the calculator.
The replay floor sets the positions of a recorded VelocityVerlet trajectory
of the same system frame by frame and asks for the forces, so it pays for
the neighbour-list updates and rebuilds that real MD causes, and nothing
else: time beyond it is the integrator's own.

The control for the per-step checks.  Before every step ReversibleVerlet
asks its ``SystemWatch`` (ase_reversible/watch.py) what changed since the
last step (calculator, its parameters, constraints, cell, pbc, numbers,
masses).  The contestant 'rv_unwatched' is 'rv_velocity' with the
instance's ``_watch`` replaced by a stub whose ``changes()`` returns no
change: the same steps without the checks, for this benchmark only (it
would miss a real change).  Both run in the same rounds; their difference
is the checks' cost in the step loop.  Since that is near the noise of a
step, ``changes()`` is also timed directly on the 'rv_velocity' contestant
after the rounds: each call inside the steps of one more block (the cost a
step pays: the force call leaves the caches cold), and in a tight loop
(warm caches: the lower bound).
"""

from __future__ import annotations

import common  # noqa: F401  (first: pins BLAS threads before numpy)

import io
import statistics
import sys
import time
from dataclasses import asdict, dataclass
from typing import Callable

import asap3
import ase
import numpy as np
from ase import units
from ase.build import bulk
from ase.calculators.emt import EMT
from ase.calculators.lj import LennardJones
from ase.md.logger import MDLogger
from ase.md.verlet import VelocityVerlet

from ase_reversible import ReversibleVerlet

TITLE = 'Cost per step'
PLOT = 'step_cost.png'

TIMESTEP_FS = 5.0
TIMESTEP = TIMESTEP_FS * units.fs
#: Move of one coordinate (Å) that makes the calculator recompute: far below
#: any neighbour-list skin, so the nudge floor never includes a rebuild.
FLOOR_NUDGE = 1e-6

# Argon Lennard-Jones parameters (eV, Å) and lattice constant (Å).
AR_EPSILON, AR_SIGMA, AR_CUTOFF, AR_LATTICE = 0.0104, 3.4, 8.5, 5.26
AR_TEMPERATURE_K, CU_TEMPERATURE_K = 60.0, 300.0

#: Repeats of the 4-atom cubic fcc cell: 144, 1000, 4000 and 32000 atoms.
REPEATS = ((3, 3, 4), (5, 5, 10), (10, 10, 10), (20, 20, 20))

#: The cost targets, checked against every run's numbers in the observations.
TARGET_RATIO_TO_VV = 1.0
TARGET_OVERHEAD_PERCENT = 5.0
TARGET_OVERHEAD_CALCULATOR = 'asap3 EMT'
TARGET_OVERHEAD_MIN_ATOMS = 4000
#: Reversible velocity counts as "slower than VelocityVerlet" above this ratio.
SLOWER_THRESHOLD = 1.05
#: The per-step checks in a tight loop: median over blocks of calls.
WATCH_CALLS, WATCH_BLOCKS = 200, 15


@dataclass(frozen=True)
class Settings:
    rounds: int
    block_seconds: float  # target wall time of one VelocityVerlet block
    min_steps: int        # per block, however slow the case
    max_steps: int
    warmup_steps: int


# Blocks of the slowest cases (ASE calculators at 4000 atoms) take
# min_steps steps, longer than block_seconds: that sets the full run time.
FULL = Settings(rounds=7, block_seconds=0.6, min_steps=2, max_steps=5000,
                warmup_steps=3)
QUICK = Settings(rounds=3, block_seconds=0.12, min_steps=2, max_steps=1000,
                 warmup_steps=2)


# -- systems and calculators -----------------------------------------------

def argon_crystal(repeat):
    atoms = bulk('Ar', 'fcc', a=AR_LATTICE, cubic=True) * repeat
    return common.thermalised(atoms, AR_TEMPERATURE_K)


def copper_crystal(repeat):
    atoms = bulk('Cu', 'fcc', cubic=True) * repeat
    return common.thermalised(atoms, CU_TEMPERATURE_K)


def ase_lj():
    return LennardJones(sigma=AR_SIGMA, epsilon=AR_EPSILON, rc=AR_CUTOFF)


def asap_lj():
    return asap3.LennardJones([18], [AR_EPSILON], [AR_SIGMA],
                              rCut=AR_CUTOFF, modified=True)


@dataclass(frozen=True)
class Calculator:
    label: str
    system: str
    build: Callable[[tuple], ase.Atoms]  # repeat -> thermalised atoms
    make_calc: Callable[[], object]
    full_max_atoms: int
    quick_max_atoms: int
    min_atoms: int = 0


#: ASE's pure-Python calculators stop at 4000 atoms: a step takes a quarter
#: (LennardJones) to over half (EMT) a second there, so these two cases take
#: about a third of the full run.  asap3's LennardJones refuses cells
#: thinner than twice its cutoff plus skin, which the 144-atom argon cell is.
CALCULATORS = (
    Calculator('ASE LennardJones', 'Ar fcc crystal', argon_crystal, ase_lj,
               full_max_atoms=4000, quick_max_atoms=150),
    Calculator('ASE EMT', 'Cu fcc crystal', copper_crystal, EMT,
               full_max_atoms=4000, quick_max_atoms=150),
    Calculator('asap3 LennardJones', 'Ar fcc crystal', argon_crystal,
               asap_lj, full_max_atoms=32000, quick_max_atoms=1000,
               min_atoms=1000),
    Calculator('asap3 EMT', 'Cu fcc crystal', copper_crystal, asap3.EMT,
               full_max_atoms=32000, quick_max_atoms=1000),
)


@dataclass(frozen=True)
class Case:
    calculator: Calculator
    repeat: tuple

    @property
    def n_atoms(self):
        return 4 * int(np.prod(self.repeat))

    def build(self):
        return self.calculator.build(self.repeat)


def step_cost_cases(quick):
    cases = []
    for calc in CALCULATORS:
        limit = calc.quick_max_atoms if quick else calc.full_max_atoms
        cases += [Case(calc, r) for r in REPEATS
                  if calc.min_atoms <= 4 * np.prod(r) <= limit]
    return cases


def logging_cases(quick):
    """One ASE LJ and one mid-size asap3 EMT case for the logger table."""
    by_label = {c.label: c for c in CALCULATORS}
    return [Case(by_label['ASE LennardJones'], REPEATS[0]),
            Case(by_label['asap3 EMT'], REPEATS[1] if quick else REPEATS[2])]


# -- contestants -----------------------------------------------------------

class NudgeFloor:
    """One full force calculation per "step", never a list rebuild."""

    def __init__(self, atoms):
        self.atoms = atoms
        self._sign = 1.0

    def run(self, steps):
        x_nc = self.atoms.arrays['positions']
        for _ in range(steps):
            # Alternate the sign so the atom stays put on average.
            x_nc[0, 0] += self._sign * FLOOR_NUDGE
            self._sign = -self._sign
            self.atoms.get_forces(md=True)


class ReplayFloor:
    """The force calls of a recorded MD run, rebuilds included."""

    def __init__(self, atoms):
        self.atoms = atoms
        self.frames = None  # [n_frames, n_atoms, 3], set by record()
        self._next = 0

    def record(self, template, make_calc, n_frames):
        """Positions of a fresh VelocityVerlet run from ``template``."""
        atoms = template.copy()
        atoms.calc = make_calc()
        frames = np.empty((n_frames,) + atoms.positions.shape)
        count = 0

        def store():
            nonlocal count
            frames[count] = atoms.positions
            count += 1

        dyn = VelocityVerlet(atoms, TIMESTEP)
        dyn.attach(store, interval=1)  # also called before the first step
        dyn.run(n_frames - 1)
        self.frames = frames
        # The frames start where this contestant's atoms already are.
        assert np.array_equal(frames[0], self.atoms.positions)

    def run(self, steps):
        if self.frames is None:
            raise RuntimeError('record() first')
        atoms, frames = self.atoms, self.frames
        for i in range(self._next, self._next + steps):
            atoms.set_positions(frames[i])
            atoms.get_forces(md=True)
        self._next += steps


class NoWatch:
    """Stands in for a ReversibleVerlet's SystemWatch: never a change."""

    def changes(self, atoms):
        return []


class TimedWatch:
    """Wraps a SystemWatch and times each ``changes()`` call where it runs."""

    def __init__(self, watch):
        self.watch, self.seconds = watch, []

    def changes(self, atoms):
        t0 = time.perf_counter()
        changed = self.watch.changes(atoms)
        self.seconds.append(time.perf_counter() - t0)
        return changed

    def __getattr__(self, name):  # take(), calc, ...: the wrapped watch's
        return getattr(self.watch, name)


def unwatched(atoms):
    """'rv_velocity' without the per-step checks: the control, see top."""
    dyn = ReversibleVerlet(atoms, TIMESTEP, scheme='velocity')
    dyn._watch = NoWatch()
    return dyn


INTEGRATORS = {
    'force': NudgeFloor,
    'replay': ReplayFloor,
    'vv': lambda atoms: VelocityVerlet(atoms, TIMESTEP),
    'rv_velocity': lambda atoms: ReversibleVerlet(atoms, TIMESTEP,
                                                  scheme='velocity'),
    'rv_unwatched': unwatched,
    'rv_position': lambda atoms: ReversibleVerlet(atoms, TIMESTEP,
                                                  scheme='position'),
    'rv_trust': lambda atoms: ReversibleVerlet(atoms, TIMESTEP,
                                               scheme='velocity',
                                               force_purity='trust'),
}
STEP_CONTESTANTS = ('force', 'replay', 'vv', 'rv_velocity', 'rv_position',
                    'rv_trust', 'rv_unwatched')
LOGGING_CONTESTANTS = ('force', 'vv', 'rv_velocity', 'rv_position')


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


def make_contestants(template, case, names, with_logger=False):
    """Each contestant on its own copy of the same atoms and calculator."""
    contestants = []
    for name in names:
        atoms = template.copy()
        atoms.calc = case.calculator.make_calc()
        runner = INTEGRATORS[name](atoms)
        if with_logger and name not in ('force', 'replay'):
            runner.attach(MDLogger(runner, atoms, io.StringIO()), interval=1)
        contestants.append(Contestant(name, runner))
    return contestants


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
    wanted = round(settings.block_seconds * steps / elapsed)
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


def time_watch(dyn, steps, calls=WATCH_CALLS, blocks=WATCH_BLOCKS):
    """Median seconds per call of ``dyn._watch.changes`` (the per-step
    checks) when nothing changed, the path every step takes: in the calls
    of a run of ``steps`` steps, and in a tight loop."""
    watch, atoms = dyn._watch, dyn.atoms
    assert watch.changes(atoms) == []
    dyn._watch = timed = TimedWatch(watch)
    try:
        dyn.run(steps)
    finally:
        dyn._watch = watch
    per_call = []
    for _ in range(blocks):
        t0 = time.perf_counter()
        for _ in range(calls):
            watch.changes(atoms)
        per_call.append((time.perf_counter() - t0) / calls)
    return statistics.median(timed.seconds), statistics.median(per_call)


def _medians(samples):
    return {k: statistics.median(v) for k, v in samples.items()}


def benchmark(case, names, settings, with_logger=False):
    """Time one case; returns a JSON-ready dict of raw and median results."""
    template = case.build()
    contestants = make_contestants(template, case, names, with_logger)
    for c in contestants:
        if not isinstance(c.runner, ReplayFloor):
            c.runner.run(settings.warmup_steps)
    by_name = {c.name: c for c in contestants}
    steps = choose_steps(by_name['vv'], settings)
    if 'replay' in by_name:
        replay = by_name['replay'].runner
        replay.record(template, case.calculator.make_calc,
                      settings.warmup_steps + steps * settings.rounds)
        replay.run(settings.warmup_steps)
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
    in_step, in_loop = (time_watch(by_name['rv_velocity'].runner, steps)
                        if 'rv_unwatched' in by_name else (None, None))
    result = {
        'calculator': case.calculator.label,
        'system': case.calculator.system,
        'n_atoms': len(template), 'with_logger': with_logger,
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
        'watch_changes_seconds': in_step,
        'watch_changes_loop_seconds': in_loop,
        'force_purity': {c.name: c.purity.todict() for c in contestants
                         if c.purity is not None},
        'grids': {c.name: c.runner.grid.todict() for c in contestants
                  if hasattr(c.runner, 'grid')},
    }
    med = result['median_seconds']
    print(f'  {case.calculator.label:20s} N={len(template):6d} '
          f'S={steps:5d}  ' + '  '.join(f'{k}={v * 1e3:.3f}ms'
                                        for k, v in med.items()),
          flush=True)
    return result


def run(quick, figures):
    settings = QUICK if quick else FULL
    print('  cost per step:', flush=True)
    steps = [benchmark(case, STEP_CONTESTANTS, settings)
             for case in step_cost_cases(quick)]
    print('  with a logger every step:', flush=True)
    logging = [benchmark(case, LOGGING_CONTESTANTS, settings,
                         with_logger=True)
               for case in logging_cases(quick)]
    plot(steps, figures / PLOT)
    return {
        'settings': {**asdict(settings), 'timestep_fs': TIMESTEP_FS,
                     'floor_nudge_angstrom': FLOOR_NUDGE,
                     'ar_temperature_K': AR_TEMPERATURE_K,
                     'cu_temperature_K': CU_TEMPERATURE_K,
                     'watch_calls': WATCH_CALLS,
                     'watch_blocks': WATCH_BLOCKS},
        'step_cost': steps,
        'logging': logging,
        'plots': [PLOT],
    }


# -- derived numbers -------------------------------------------------------

#: The process's CPU time: single-threaded here, so on a machine shared with
#: other jobs it is the step's cost without the waits for a core.
CPU = 'median_cpu_seconds'

def ratio(r, name, reference='vv', clock='median_seconds'):
    med = r[clock]
    return med[name] / med[reference]


def paired_ratios(r, name, reference='vv'):
    """Per-round ratios: both blocks of a round ran close together."""
    wall = r['per_step_seconds']
    return [a / b for a, b in zip(wall[name], wall[reference])]


def overhead_percent(r, name, floor='replay', clock='median_seconds'):
    """Time beyond the floor, in % of the floor."""
    med = r[clock]
    return 100 * (med[name] - med[floor]) / med[floor]


def in_force_calls(r, key):
    return r[key] / r['median_seconds']['force']


def wall_over_cpu(r):
    """Largest wall/CPU ratio of a case's medians: 1.00 on a quiet machine."""
    return max(r['median_seconds'][k] / r['median_cpu_seconds'][k]
               for k in r['median_seconds'])


def position_extra_calls(r):
    """Extra cost of 'position' over 'velocity', in nudge force calls."""
    med = r['median_seconds']
    return (med['rv_position'] - med['rv_velocity']) / med['force']


def by_calculator(results):
    groups = {}
    for r in results:
        groups.setdefault(r['calculator'], []).append(r)
    return {k: sorted(v, key=lambda r: r['n_atoms'])
            for k, v in groups.items()}


# -- plot ------------------------------------------------------------------

def plot(results, path):
    plt = common.pyplot()
    from matplotlib.lines import Line2D
    from matplotlib.ticker import FuncFormatter, NullFormatter
    fig, (left, right) = plt.subplots(1, 2, figsize=(11, 4.3))
    colours = plt.rcParams['axes.prop_cycle'].by_key()['color']
    sizes = sorted({r['n_atoms'] for r in results})
    for colour, (label, rs) in zip(colours, by_calculator(results).items()):
        n = [r['n_atoms'] for r in rs]
        left.plot(n, [ratio(r, 'rv_velocity') for r in rs], 'o-',
                  color=colour, label=label)
        right.plot(n, [overhead_percent(r, 'rv_velocity') for r in rs],
                   'o-', color=colour)
        right.plot(n, [overhead_percent(r, 'vv') for r in rs], 'x--',
                   color=colour, alpha=0.7)
    left.axhline(TARGET_RATIO_TO_VV, color='k', lw=0.8, ls=':',
                 label=f'target: ≤ {TARGET_RATIO_TO_VV:g}')
    left.set_ylabel('Reversible (velocity) / VelocityVerlet, per step')
    left.set_title('Time per step relative to VelocityVerlet')
    right.axhline(TARGET_OVERHEAD_PERCENT, color='k', lw=0.8, ls=':')
    right.axhline(0, color='grey', lw=0.5)
    # Overheads span from a few % (noise around 0) to a few hundred %.
    right.set_yscale('symlog', linthresh=10)
    right.margins(y=0.08)
    low, high = right.get_ylim()
    right.set_yticks([t for t in (-200, -100, -50, -20, -10, -5, 0, 5, 10,
                                  20, 50, 100, 200, 500, 1000)
                      if low <= t <= high])
    right.yaxis.set_major_formatter(FuncFormatter(lambda v, _: f'{v:g}'))
    right.set_ylabel('time beyond the replay floor, % of the floor')
    right.set_title('Overhead beyond the force calls of real MD')
    right.legend(loc='best', handles=[
        Line2D([], [], color='k', marker='o', label='Reversible (velocity)'),
        Line2D([], [], color='k', marker='x', ls='--', alpha=0.7,
               label='VelocityVerlet'),
        Line2D([], [], color='k', lw=0.8, ls=':',
               label=f'target ({TARGET_OVERHEAD_CALCULATOR}, '
                     f'N ≥ {TARGET_OVERHEAD_MIN_ATOMS}): '
                     f'< {TARGET_OVERHEAD_PERCENT:g}%')], fontsize=8)
    left.legend(fontsize=8)
    for ax in (left, right):
        ax.set_xscale('log')
        ax.set_xticks(sizes)
        ax.xaxis.set_major_formatter(FuncFormatter(lambda v, _: f'{v:g}'))
        ax.xaxis.set_minor_formatter(NullFormatter())
        ax.set_xlabel('number of atoms')
        ax.grid(True, which='major', alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


# -- Markdown --------------------------------------------------------------

def ms(seconds):
    """Milliseconds with three significant digits, no exponent."""
    v = seconds * 1e3
    for limit, decimals in ((100, 0), (10, 1), (1, 2)):
        if abs(v) >= limit:
            return f'{v:.{decimals}f}'
    return f'{v:.3f}'


def with_ratio(r, name):
    return f"{ms(r['median_seconds'][name])} (×{ratio(r, name):.2f})"


def beyond(r, name, floor):
    med = r['median_seconds']
    return (f'{ms(med[name] - med[floor])} '
            f'({overhead_percent(r, name, floor):+.0f}%)')


def clean_fraction(r, name):
    entry = r['clean_recomputations'].get(name)
    if entry is None or r['force_purity'][name]['mode'] != 'guarded':
        return '—'
    k, n = entry['recomputations'], entry['force_calls']
    return f'{100 * k / n:.2g}% ({k}/{n})'


def case_label(r):
    return f"{r['calculator']}, N={r['n_atoms']}"


def step_cost_table(results):
    header = ('calculator', 'N', 'steps × rounds', 'purity (auto)',
              'nudge floor (ms)', 'replay floor (ms)',
              'VelocityVerlet (ms/step)',
              'Reversible velocity (ms/step, ×VV)',
              'Reversible position (ms/step, ×VV)',
              'Reversible trust (ms/step, ×VV)')
    rows = [(r['calculator'], r['n_atoms'],
             f"{r['steps_per_block']} × {r['rounds']}",
             r['force_purity']['rv_velocity']['mode'],
             ms(r['median_seconds']['force']),
             ms(r['median_seconds']['replay']),
             ms(r['median_seconds']['vv']),
             with_ratio(r, 'rv_velocity'), with_ratio(r, 'rv_position'),
             with_ratio(r, 'rv_trust'))
            for r in results]
    return common.markdown_table(header, rows)


def overhead_table(results):
    header = ('calculator', 'N', 'replay − nudge floor (ms, %)',
              'VV beyond replay floor (ms, %)',
              'Reversible velocity beyond replay floor (ms, %)',
              'Reversible velocity beyond nudge floor (ms, %)',
              'clean recomputations, velocity / position',
              'round spread', 'wall / CPU')
    rows = [(r['calculator'], r['n_atoms'],
             beyond(r, 'replay', 'force'),
             beyond(r, 'vv', 'replay'),
             beyond(r, 'rv_velocity', 'replay'),
             beyond(r, 'rv_velocity', 'force'),
             f"{clean_fraction(r, 'rv_velocity')} / "
             f"{clean_fraction(r, 'rv_position')}",
             f"{100 * max(r['spread'].values()):.0f}%",
             f'{wall_over_cpu(r):.2f}')
            for r in results]
    return common.markdown_table(header, rows)


def logging_table(results):
    header = ('calculator', 'N', 'nudge floor (ms)',
              'VelocityVerlet + logger (ms/step)',
              'Reversible velocity + logger (ms/step, ×VV)',
              'Reversible position + logger (ms/step, ×VV)',
              'position − velocity (ms/step, in nudge force calls)',
              'round spread', 'wall / CPU')
    rows = []
    for r in results:
        med = r['median_seconds']
        rows.append((r['calculator'], r['n_atoms'], ms(med['force']),
                     ms(med['vv']), with_ratio(r, 'rv_velocity'),
                     with_ratio(r, 'rv_position'),
                     f"{ms(med['rv_position'] - med['rv_velocity'])} "
                     f'({position_extra_calls(r):.2f})',
                     f"{100 * max(r['spread'].values()):.0f}%",
                     f'{wall_over_cpu(r):.2f}'))
    return common.markdown_table(header, rows)


def checks_table(results):
    header = ('calculator', 'N', 'Reversible velocity (ms/step)',
              'checks bypassed (ms/step)',
              'with / without checks (per-round range)',
              'difference of medians (µs/step)',
              'changes() in the steps (µs/call, % of step)',
              'changes() in a tight loop (µs/call)', 'round spread')
    rows = []
    for r in results:
        med = r['median_seconds']
        paired = paired_ratios(r, 'rv_velocity', 'rv_unwatched')
        diff = 1e6 * (med['rv_velocity'] - med['rv_unwatched'])
        watch = r['watch_changes_seconds']
        spread = max(r['spread'][k] for k in ('rv_velocity', 'rv_unwatched'))
        rows.append((r['calculator'], r['n_atoms'], ms(med['rv_velocity']),
                     ms(med['rv_unwatched']),
                     f"×{ratio(r, 'rv_velocity', 'rv_unwatched'):.3f} "
                     f'(×{min(paired):.2f} to ×{max(paired):.2f})',
                     f'{diff:+.1f}' if abs(diff) < 100 else f'{diff:+.0f}',
                     f'{1e6 * watch:.2f} '
                     f"({100 * watch / med['rv_velocity']:.2g}%)",
                     f"{1e6 * r['watch_changes_loop_seconds']:.2f}",
                     f'{100 * spread:.0f}%'))
    return common.markdown_table(header, rows)


def checks_lines(results):
    """The per-step checks, alone and in the step loop."""
    def share(r):
        return r['watch_changes_seconds'] / r['median_seconds']['rv_velocity']

    def with_without(r):
        return ratio(r, 'rv_velocity', 'rv_unwatched')

    alone = sorted(results, key=lambda r: r['watch_changes_seconds'])
    tight = [1e6 * r['watch_changes_loop_seconds'] for r in results]
    top = max(results, key=share)
    loop = sorted(results, key=with_without)
    unresolved = sum(min(p) <= 1 <= max(p) for p in (
        paired_ratios(r, 'rv_velocity', 'rv_unwatched') for r in results))
    return (f'- The per-step checks (`SystemWatch.changes`, timed in the '
            f"steps) cost {1e6 * alone[0]['watch_changes_seconds']:.2f} µs "
            f'({case_label(alone[0])}) to '
            f"{1e6 * alone[-1]['watch_changes_seconds']:.2f} µs "
            f'({case_label(alone[-1])}) per call, at most '
            f'{100 * share(top):.2g}% of a Reversible velocity step '
            f'({case_label(top)}); in a tight loop {min(tight):.2f} to '
            f'{max(tight):.2f} µs.\n'
            f'- In the step loop, Reversible velocity with / without the '
            f'checks ranges from ×{with_without(loop[0]):.3f} '
            f'({case_label(loop[0])}) to ×{with_without(loop[-1]):.3f} '
            f'({case_label(loop[-1])}); the per-round ratios lie on both '
            f'sides of 1 in {unresolved} of {len(results)} cases.')


def cache_table(results):
    header = ('calculator', 'N', 'nudge floor (ms)',
              'get_forces() again (ms, in force calls)',
              'get_potential_energy() after get_forces() '
              '(ms, in force calls)')
    rows = [(r['calculator'], r['n_atoms'], ms(r['median_seconds']['force']),
             *(f'{ms(r[key])} ({in_force_calls(r, key):.2f})'
               for key in ('get_forces_again_seconds',
                           'energy_after_forces_seconds')))
            for r in results]
    return common.markdown_table(header, rows)


def target_lines(results):
    """The cost targets, judged on this run's numbers."""
    out = []
    for name, scheme in (('rv_velocity', 'velocity'),
                         ('rv_position', 'position')):
        missed = [r for r in results
                  if ratio(r, name) > TARGET_RATIO_TO_VV]
        head = (f"- Reversible '{scheme}' (force_purity='auto') per step "
                f'≤ VelocityVerlet: met in {len(results) - len(missed)} of '
                f'{len(results)} cases')
        if not missed:
            out.append(head + '.')
            continue

        def item(r):
            paired = paired_ratios(r, name)
            med = r['median_seconds']
            consistent = ('slower in every round'
                          if min(paired) > TARGET_RATIO_TO_VV
                          else 'not slower in every round')
            return (f'{case_label(r)}: ×{ratio(r, name):.3f} '
                    f"(+{ms(med[name] - med['vv'])} ms/step; per-round "
                    f'ratios ×{min(paired):.2f} to ×{max(paired):.2f}, '
                    f'{consistent}; on CPU time '
                    f'×{ratio(r, name, clock=CPU):.3f})')
        out.append(head + '; missed in ' + '; '.join(map(item, missed))
                   + '.')
    big = [r for r in results
           if r['calculator'] == TARGET_OVERHEAD_CALCULATOR
           and r['n_atoms'] >= TARGET_OVERHEAD_MIN_ATOMS]
    if not big:
        out.append(f'- Overhead target ({TARGET_OVERHEAD_CALCULATOR}, '
                   f'N ≥ {TARGET_OVERHEAD_MIN_ATOMS}): no such case in '
                   f'this run.')
    for r in big:
        value = overhead_percent(r, 'rv_velocity')
        verdict = 'met' if value < TARGET_OVERHEAD_PERCENT else 'missed'
        out.append(f"- Reversible 'velocity' beyond the replay floor "
                   f'< {TARGET_OVERHEAD_PERCENT:g}% ({case_label(r)}): '
                   f'{value:+.1f}%, {verdict} (on CPU time '
                   f"{overhead_percent(r, 'rv_velocity', clock=CPU):+.1f}%; "
                   f"VelocityVerlet: {overhead_percent(r, 'vv'):+.1f}%, "
                   f"on CPU time {overhead_percent(r, 'vv', clock=CPU):+.1f}%)"
                   '.')
    return '\n'.join(out)


def summary(step_results, log_results):
    """Observations computed from this run's numbers."""
    out = []
    vel = sorted(step_results, key=lambda r: ratio(r, 'rv_velocity'))
    lo, hi = vel[0], vel[-1]
    out.append(f"- Reversible velocity / VelocityVerlet ranges from "
               f"×{ratio(lo, 'rv_velocity'):.2f} ({case_label(lo)}) to "
               f"×{ratio(hi, 'rv_velocity'):.2f} ({case_label(hi)}).")
    cpu = sorted(step_results,
                 key=lambda r: ratio(r, 'rv_velocity', clock=CPU))
    out.append(f"- On CPU time the same ratio ranges from "
               f"×{ratio(cpu[0], 'rv_velocity', clock=CPU):.2f} "
               f"({case_label(cpu[0])}) to "
               f"×{ratio(cpu[-1], 'rv_velocity', clock=CPU):.2f} "
               f"({case_label(cpu[-1])}).")
    slower = [r for r in step_results
              if ratio(r, 'rv_velocity') > SLOWER_THRESHOLD]
    if slower:
        def excess(r):
            med = r['median_seconds']
            return (f"{case_label(r)}: "
                    f"+{100 * (ratio(r, 'rv_velocity') - 1):.0f}% "
                    f"(+{ms(med['rv_velocity'] - med['vv'])} ms/step)")
        out.append(f'- Reversible velocity is more than '
                   f'{100 * (SLOWER_THRESHOLD - 1):.0f}% slower than '
                   f'VelocityVerlet in: '
                   + '; '.join(map(excess, slower)) + '.')
    else:
        out.append(f'- Reversible velocity is nowhere more than '
                   f'{100 * (SLOWER_THRESHOLD - 1):.0f}% slower than '
                   f'VelocityVerlet.')
    rebuild = sorted(step_results,
                     key=lambda r: overhead_percent(r, 'replay', 'force'))
    out.append(f'- The replay floor (force calls of real MD, list rebuilds '
               f'included) exceeds the nudge floor by '
               f"{overhead_percent(rebuild[0], 'replay', 'force'):+.0f}% "
               f'({case_label(rebuild[0])}) to '
               f"{overhead_percent(rebuild[-1], 'replay', 'force'):+.0f}% "
               f'({case_label(rebuild[-1])}).')
    purity_cost = [ratio(r, 'rv_velocity', 'rv_trust') for r in step_results]
    out.append(f"- Force purity handling (auto vs 'trust', velocity scheme) "
               f"costs ×{min(purity_cost):.2f} to ×{max(purity_cost):.2f}.")
    out.append(checks_lines(step_results))
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
                   f'{100 * max(fractions):.2g}% (each recomputes the '
                   f'forces from a freshly built neighbour list).')

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
                   f'{position_extra_calls(r):.2f} nudge force calls per '
                   f"step more than 'velocity' ({case_label(r)}).")
    worst = max(step_results + log_results, key=wall_over_cpu)
    out.append(f'- Largest wall / CPU time ratio: {wall_over_cpu(worst):.2f} '
               f'({case_label(worst)}); well above 1 means other processes '
               f'took the CPU during the blocks and the wall times there are '
               f'noisier.')
    return '\n'.join(out)


def render(results):
    s = results['settings']
    steps, logging = results['step_cost'], results['logging']
    systems = '; '.join(sorted({f"{r['calculator']}: {r['system']}"
                                for r in steps}))
    return f"""\
How much a step of `ReversibleVerlet` costs against ASE's `VelocityVerlet`
and against the calculator's force call alone, for periodic crystals
({systems}) at {s['ar_temperature_K']:g} K (Ar) and \
{s['cu_temperature_K']:g} K (Cu), time step {s['timestep_fs']:g} fs.

![Reversible velocity / VelocityVerlet per step (left) and time beyond the \
replay floor in % of the floor (right), against the number of atoms]\
(benchmarks/{results['plots'][0]})

### Method

Each contestant runs on its own copy of the same thermalised atoms
(Maxwell-Boltzmann, seed 0) with its own fresh calculator. After
{s['warmup_steps']} warm-up steps each, the contestants run blocks of the
same number of steps, chosen per case so that a VelocityVerlet block takes
about {s['block_seconds']:g} s (at least {s['min_steps']} steps), in
{s['rounds']} rounds with the order rotating each round. Times are medians
over rounds of block time / steps; ratios are ratios of medians. "Round
spread" is the largest (max − min) / median over the contestants of a case:
differences smaller than that are noise. "Wall / CPU" is the largest ratio
of a contestant's median wall time to its median CPU time
(`time.process_time`, also in the JSON): near 1.00 the process had the CPU
to itself. BLAS runs on one thread so that numpy's thread hand-offs do not
add scheduler delays to the steps.

- **nudge floor**: one atom moved by {s['floor_nudge_angstrom']:g} Å, then
  `atoms.get_forces(md=True)`: a full calculation that never rebuilds the
  neighbour list.
- **replay floor**: the positions of a VelocityVerlet run of the same system
  from the same start (recorded before the rounds, fresh calculator), set
  frame by frame with `atoms.set_positions` followed by
  `atoms.get_forces(md=True)`. It includes the neighbour-list updates and
  rebuilds that MD really causes, so time beyond it is the integrator's
  own work (plus its extra force calls, if any).
- **VelocityVerlet**: `ase.md.verlet.VelocityVerlet`.
- **Reversible velocity / position**: `ReversibleVerlet(scheme=...)` with
  `force_purity='auto'` (exact reversal): 'sorted' for ASE calculators,
  'guarded' for asap3.
- **Reversible trust**: `ReversibleVerlet(scheme='velocity',
  force_purity='trust')`: the cost without any purity handling. *Not exact*
  for these calculators; a baseline only.
- **checks bypassed** (`rv_unwatched` in the JSON): Reversible velocity
  with the integrator's `SystemWatch` replaced by a stub that never reports
  a change (benchmark only): the control for the checks made before every
  step. See "Cost of the per-step checks".
- **clean recomputations**: for 'guarded', the share of force evaluations
  (one per step) whose kick was recomputed from a freshly built neighbour
  list, during the timed blocks, as count / force evaluations.

### Time per step

{step_cost_table(steps)}

### Overhead beyond the force call

Median step time minus a floor, in ms and in % of that floor.

{overhead_table(steps)}

### Cost of the per-step checks

Before every step `ReversibleVerlet` compares the calculator, its
parameters, the constraints, cell, pbc, atomic numbers and masses with a
snapshot (`SystemWatch.changes`, `ase_reversible/watch.py`), then the
positions and momenta. "Checks bypassed" is Reversible velocity with that
comparison replaced by a stub reporting no change, timed in the same
rounds: the difference of the medians is the checks' cost in the step loop,
noise where it is within the round spread (of these two contestants) or
the per-round ratios lie on both sides of 1. The comparison is also timed
directly on the Reversible velocity contestant after the rounds, with
nothing changed (the path of every step): "in the steps" is the median of
its calls (`time.perf_counter` around each) during one more block of the
same number of steps, in µs and in % of that contestant's median step;
"in a tight loop" is the median over {s['watch_blocks']} blocks of
{s['watch_calls']} back-to-back calls. The tight loop runs with warm caches
and is the lower bound; in the steps the force call has left the caches
cold, and that is what a step pays.

{checks_table(steps)}

### Targets

Judged on the wall-time medians above; a ratio within the round spread of
1 is not resolved by this run. CPU time is given beside them: the process
is single-threaded, so where wall / CPU is well above 1 (other processes
held the CPU), CPU time is the steadier estimate of the cost.

{target_lines(steps)}

### Scheme cost under logging

The same measurement with an `MDLogger` (writing to an `io.StringIO`)
attached every step (no replay floor). Kick-drift-kick ('velocity') ends a
step with a force calculation at the new positions, so the logger finds the
energy in the calculator's cache (if the calculator keeps it; see the
diagnostic below); drift-kick-drift ('position') ends a step between force
calculations, so the logger's energy is a calculation of its own at every
logged step. The second to last column gives that difference in units of
the nudge floor.

{logging_table(logging)}

### Diagnostic: what the calculators cache

Asked again at unchanged positions (on the nudge-floor contestant after the
rounds; median of three blocks): `get_forces()` repeated, as VelocityVerlet
does at the start and end of each step, and `get_potential_energy()` right
after `get_forces()`, as a logger does. A cache hit costs microseconds; a
recomputation costs up to a whole force call.

{cache_table(steps)}

### Observations (computed from this run)

{summary(steps, logging)}
"""


if __name__ == '__main__':
    import run_all
    sys.exit(run_all.main(['--only', 'step_cost'] + sys.argv[1:]))
