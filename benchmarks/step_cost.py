"""Cost per MD step of ReversibleVerlet against ASE's VelocityVerlet
(the contestants and the method: docs/benchmarks.md, "Cost per step").
"""

from __future__ import annotations

import common  # noqa: F401  (first: pins BLAS threads before numpy)

import io
import statistics
import time
from dataclasses import asdict, dataclass
from typing import Callable

import asap3
import ase
import numpy as np
import systems
from ase import units
from ase.calculators.emt import EMT
from ase.md.logger import MDLogger
from ase.md.verlet import VelocityVerlet
from harness import (FLOOR_NUDGE, Contestant, Settings, choose_steps, medians,
                     per_step, time_cached_queries, time_interleaved)

from ase_reversible import ReversibleVerlet
from ase_reversible.app import systems as app_systems

TIMESTEP_FS = 5.0
TIMESTEP = TIMESTEP_FS * units.fs
AR_TEMPERATURE_K, CU_TEMPERATURE_K = 60.0, 300.0

#: Repeats of the 4-atom cubic fcc cell: 144, 1000, 4000 and 32000 atoms.
REPEATS = ((3, 3, 4), (5, 5, 10), (10, 10, 10), (20, 20, 20))

#: The per-step checks in a tight loop: median over blocks of calls.
WATCH_CALLS, WATCH_BLOCKS = 200, 15


# Blocks of the slowest cases (ASE calculators at 4000 atoms) take
# min_steps steps, longer than block_seconds: that sets the full run time.
FULL = Settings(rounds=7, block_seconds=0.6, min_steps=2, max_steps=5000,
                warmup_steps=3)
QUICK = Settings(rounds=3, block_seconds=0.12, min_steps=2, max_steps=1000,
                 warmup_steps=2)
#: The overhead cases: steps of tens of microseconds, so more and shorter
#: blocks; the median over many rounds resolves differences of a few µs.
OVERHEAD_FULL = Settings(rounds=21, block_seconds=0.25, min_steps=100,
                         max_steps=20000, warmup_steps=10)
OVERHEAD_QUICK = Settings(rounds=3, block_seconds=0.05, min_steps=20,
                          max_steps=2000, warmup_steps=5)

#: (atoms, system) of the overhead cases: argon icosahedra of 2, 3, 4 and
#: 6 shells, then fcc crystals of (5, 5, 10) and (10, 10, 10) cubic cells.
OVERHEAD_SYSTEMS = ((13, 'Ar icosahedron'), (55, 'Ar icosahedron'),
                    (147, 'Ar icosahedron'), (561, 'Ar icosahedron'),
                    (1000, 'Ar fcc crystal'), (4000, 'Ar fcc crystal'))
QUICK_OVERHEAD_SIZES = (13, 147, 1000)


# -- systems and calculators -----------------------------------------------

def argon_crystal(repeat):
    return app_systems.argon_bulk(repeat, AR_TEMPERATURE_K)


def copper_crystal(repeat):
    return app_systems.copper_bulk(repeat, CU_TEMPERATURE_K, rattle=0)


def overhead_system(n_atoms):
    """Thermalised argon of ``n_atoms`` for the overhead cases."""
    shells = {13: 2, 55: 3, 147: 4, 561: 6}
    if n_atoms in shells:
        atoms = app_systems.argon_cluster(shells[n_atoms], AR_TEMPERATURE_K)
    else:
        repeat = {1000: (5, 5, 10), 4000: (10, 10, 10)}[n_atoms]
        atoms = argon_crystal(repeat)
    assert len(atoms) == n_atoms
    return atoms


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
    Calculator('ASE LennardJones', 'Ar fcc crystal', argon_crystal,
               app_systems.argon_lj,
               full_max_atoms=4000, quick_max_atoms=150),
    Calculator('ASE EMT', 'Cu fcc crystal', copper_crystal, EMT,
               full_max_atoms=4000, quick_max_atoms=150),
    Calculator('asap3 LennardJones', 'Ar fcc crystal', argon_crystal,
               systems.asap3_argon_lj(), full_max_atoms=32000,
               quick_max_atoms=1000,
               min_atoms=1000),
    Calculator('asap3 EMT', 'Cu fcc crystal', copper_crystal, asap3.EMT,
               full_max_atoms=32000, quick_max_atoms=1000),
)


def step_cost_cases(quick):
    """(calculator, repeat) of each case."""
    return [(calc, r) for calc in CALCULATORS for r in REPEATS
            if calc.min_atoms <= 4 * np.prod(r)
            <= (calc.quick_max_atoms if quick else calc.full_max_atoms)]


def logging_cases(quick):
    """One ASE LJ and one mid-size asap3 EMT case for the logger table."""
    by_label = {c.label: c for c in CALCULATORS}
    return [(by_label['ASE LennardJones'], REPEATS[0]),
            (by_label['asap3 EMT'], REPEATS[1] if quick else REPEATS[2])]


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


class Timed:
    """Stands in for ``wrapped`` and times each call of its method
    ``method`` where it runs (``seconds``); every other attribute is the
    wrapped object's."""

    def __init__(self, wrapped, method):
        self.wrapped, self.seconds = wrapped, []
        call = getattr(wrapped, method)

        def timed(*args):
            t0 = time.perf_counter()
            try:
                return call(*args)
            finally:
                self.seconds.append(time.perf_counter() - t0)
        setattr(self, method, timed)

    def __getattr__(self, name):
        return getattr(self.wrapped, name)


def nothing():
    """An observer that does nothing."""


def observed(atoms):
    """'rv_velocity' with an observer: the per-step checks run, see top."""
    dyn = ReversibleVerlet(atoms, TIMESTEP, scheme='velocity')
    dyn.attach(nothing)
    return dyn


def unwatched(atoms):
    """'rv_observed' without the per-step checks: the control, see top."""
    dyn = observed(atoms)
    dyn._watch = NoWatch()
    return dyn


def velocity_verlet(atoms):
    return VelocityVerlet(atoms, TIMESTEP)


def trusting(atoms):
    """'rv_velocity' with no purity handling at all: forces taken as they
    come and the spot check, which would stop asap3 within a few hundred
    steps, switched off.  Not exact with asap3; the baseline of what the
    handling costs."""
    dyn = ReversibleVerlet(atoms, TIMESTEP, scheme='velocity',
                           force_purity='trust')
    dyn.force_purity.spot_check = None
    return dyn


INTEGRATORS = {
    'force': NudgeFloor,
    'replay': ReplayFloor,
    'vv': velocity_verlet,
    'vv_twin': velocity_verlet,
    'rv_velocity': lambda atoms: ReversibleVerlet(atoms, TIMESTEP,
                                                  scheme='velocity'),
    'rv_observed': observed,
    'rv_unwatched': unwatched,
    'rv_position': lambda atoms: ReversibleVerlet(atoms, TIMESTEP,
                                                  scheme='position'),
    'rv_trust': trusting,
}
STEP_CONTESTANTS = ('force', 'replay', 'vv', 'vv_twin', 'rv_velocity',
                    'rv_position', 'rv_trust', 'rv_observed', 'rv_unwatched')
LOGGING_CONTESTANTS = ('force', 'vv', 'rv_velocity', 'rv_position')
#: With CachedForces 'auto' is 'trust': rv_trust would be rv_velocity again.
OVERHEAD_CONTESTANTS = ('force', 'vv', 'rv_velocity', 'rv_position')


def make_contestants(template, calc, names, with_logger=False):
    """Each contestant on its own copy of the same atoms and calculator."""
    contestants = []
    for name in names:
        atoms = template.copy()
        atoms.calc = calc.make_calc()
        runner = INTEGRATORS[name](atoms)
        if with_logger and name not in ('force', 'replay'):
            runner.attach(MDLogger(runner, atoms, io.StringIO()), interval=1)
        contestants.append(Contestant(name, runner))
    return contestants


def time_watch(dyn, steps, calls=WATCH_CALLS, blocks=WATCH_BLOCKS):
    """Median seconds per call of ``dyn._watch.changes`` (the per-step
    checks) when nothing changed, the path every step takes: in the calls
    of a run of ``steps`` steps, and in a tight loop."""
    watch, atoms = dyn._watch, dyn.atoms
    assert watch.changes(atoms) == []
    dyn._watch = timed = Timed(watch, 'changes')
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


def benchmark(calc, repeat, names, settings, with_logger=False):
    """Time one case; returns a JSON-ready dict of raw and median results."""
    template = calc.build(repeat)
    contestants = make_contestants(template, calc, names, with_logger)
    for c in contestants:
        if not isinstance(c.runner, ReplayFloor):
            c.runner.run(settings.warmup_steps)
    by_name = {c.name: c for c in contestants}
    steps = choose_steps(by_name['vv'].runner.run, settings)
    if 'replay' in by_name:
        replay = by_name['replay'].runner
        replay.record(template, calc.make_calc,
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
    in_step, in_loop = (time_watch(by_name['rv_observed'].runner, steps)
                        if 'rv_unwatched' in by_name else (None, None))
    result = {
        'calculator': calc.label, 'system': calc.system,
        'n_atoms': len(template), 'with_logger': with_logger,
        'steps_per_block': steps, 'rounds': settings.rounds,
        **per_step(wall, cpu),
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
    print(f'  {calc.label:20s} N={len(template):6d} '
          f'S={steps:5d}  ' + '  '.join(f'{k}={v * 1e3:.3f}ms'
                                        for k, v in med.items()),
          flush=True)
    return result


def overhead(n_atoms, system, settings):
    """The integrators' time per step beyond the force call of
    ``CachedForces`` (see top); JSON-ready."""
    template = overhead_system(n_atoms)
    contestants = []
    for name in OVERHEAD_CONTESTANTS:
        atoms = template.copy()
        atoms.calc = systems.CachedForces(n_atoms)
        contestants.append(Contestant(name, INTEGRATORS[name](atoms)))
    for c in contestants:
        c.runner.run(settings.warmup_steps)
    by_name = {c.name: c for c in contestants}
    steps = choose_steps(by_name['vv'].runner.run, settings)
    wall, cpu = time_interleaved(contestants, steps, settings.rounds)
    med = medians(wall)
    result = {
        'system': system, 'n_atoms': n_atoms,
        'steps_per_block': steps, 'rounds': settings.rounds,
        **per_step(wall, cpu),
        'overhead_seconds': {k: v - med['force'] for k, v in med.items()
                             if k != 'force'},
        'force_purity': {c.name: c.purity.todict() for c in contestants
                         if c.purity is not None},
    }
    print(f'  {system:15s} N={n_atoms:6d} S={steps:5d}  '
          + '  '.join(f'{k}={v * 1e6:.1f}µs'
                      for k, v in result['overhead_seconds'].items())
          + f"  (force call {med['force'] * 1e6:.1f}µs)", flush=True)
    return result


def run(quick):
    settings = QUICK if quick else FULL
    print('  integrator overhead (CachedForces):', flush=True)
    overhead_settings = OVERHEAD_QUICK if quick else OVERHEAD_FULL
    overheads = [overhead(n, system, overhead_settings)
                 for n, system in OVERHEAD_SYSTEMS
                 if not quick or n in QUICK_OVERHEAD_SIZES]
    print('  cost per step:', flush=True)
    steps = [benchmark(calc, repeat, STEP_CONTESTANTS, settings)
             for calc, repeat in step_cost_cases(quick)]
    print('  with a logger every step:', flush=True)
    logging = [benchmark(calc, repeat, LOGGING_CONTESTANTS, settings,
                         with_logger=True)
               for calc, repeat in logging_cases(quick)]
    return {
        'settings': {**asdict(settings), 'timestep_fs': TIMESTEP_FS,
                     'floor_nudge_angstrom': FLOOR_NUDGE,
                     'ar_temperature_K': AR_TEMPERATURE_K,
                     'cu_temperature_K': CU_TEMPERATURE_K,
                     'watch_calls': WATCH_CALLS,
                     'watch_blocks': WATCH_BLOCKS,
                     'overhead': asdict(overhead_settings)},
        'step_cost': steps,
        'logging': logging,
        'overhead': overheads,
    }

