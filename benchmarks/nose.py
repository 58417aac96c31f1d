"""ReversibleNose against ASE's thermostats: sampling, exact reversal,
memory (one fresh process per point, ``--memory-worker``), cost per step
(``--only nose``: 12-15 minutes, ~15 s with ``--quick``).
"""

from __future__ import annotations

import common  # noqa: F401  (first: pins BLAS threads before numpy)

import contextlib
import gc
import json
import os
import sys
import time
import tracemalloc
import warnings
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
from ase import units
from harness import (BLOCKS, FORCE_EVERY, WINDOW_C, NoseSampler,
                     against_reference, nose_statistics,
                     resident_bytes, speed_case, there_and_back)
from systems import (FRICTION_PER_FS, NOSE_SYSTEMS, SEED, START_FACTOR,
                     TDAMP_STEPS, THERMOSTAT_SPEED, THERMOSTATS, ase_langevin,
                     reversible_nose)


#: Seed of the random loss gradient of the memory points.
LOSS_SEED = 1
#: The goals the page judges against.
TEMPERATURE_GOAL_PERCENT = 1.0
KS_LEVEL = 0.01
POTENTIAL_GOAL_SE = 2.0
MEMORY_GOAL_RATIO = 1.1
COST_GOAL_RATIO = 1.05
MEMORY_PARALLEL = 2

SYSTEMS = NOSE_SYSTEMS
MEMORY_SYSTEM = SYSTEMS[0]


@dataclass(frozen=True)
class Lengths:
    equilibration: int
    round_trip: int          # forward steps, equilibration included
    memory_steps: tuple


FULL = Lengths(equilibration=2000, round_trip=100_000,
               memory_steps=(1000, 10_000, 100_000))
QUICK = Lengths(equilibration=200, round_trip=1000, memory_steps=(100, 1000))
#: Copper, asap3 EMT: 1000 and 4000 atoms.
SPEED_CASES = ((SYSTEMS[1], (5, 5, 10)), (SYSTEMS[1], (10, 10, 10)))
#: ASE Langevin, VelocityVerlet and ReversibleVerlet on Cu 4000 at 5 fs, and
#: a repeated get_forces(), are in the thermostat section's cost table.
SPEED_CONTESTANTS = ('reversible_nose', 'ase_nose_hoover_chain')


def sampling_system(system, lengths):
    """ReversibleNose there and back against ASE's Langevin."""
    atoms = system.atoms()
    dyn, ours, trip = there_and_back(
        lambda: reversible_nose(atoms, system), NoseSampler,
        lengths.round_trip, at_turn=lambda dyn: {
            'real_time_forward_fs': dyn.get_time() / units.fs},
        snapshot=lambda dyn: dyn.counts)
    start, end = trip['start'], dyn.counts
    round_trip = {
        'steps_each_way': lengths.round_trip, 'moved': trip['moved'],
        'counts_equal': {name: bool(np.array_equal(end[name], start[name]))
                         for name in start},
        **{k: trip[k] for k in ('positions_equal', 'momenta_equal')},
        'time_after_fs': dyn.get_time() / units.fs,
        **{k: trip[k] for k in ('real_time_forward_fs', 'forward_seconds',
                                'back_seconds', 'warnings')}}
    first = lengths.equilibration + 1
    result = against_reference(system, first, ('reversible_nose', ours),
                               'ase_langevin', ase_langevin,
                               lengths.round_trip)
    thermostat = {'degrees_of_freedom': dyn.degrees_of_freedom,
                  'tdamp_fs': dyn.tdamp / units.fs,
                  **nose_statistics(ours, first, system.timestep_fs)}
    # The pi kicks read the momenta between the two half kicks, so those
    # are what the thermostat steers to T; for a harmonic mode the momenta
    # at the step's end are then cooler by (h omega)**2 / 4, h = dt / s.
    thermostat['harmonic_kinetic_offset_percent'] = (
        -100 * thermostat['real_timestep_fs']['rms']**2
        * result['sampling']['reversible_nose']['mean_omega_squared_per_fs2']
        / 4)
    return {**result, 'equilibration_steps': lengths.equilibration,
            'thermostat': thermostat, 'round_trip': round_trip}


# -- memory: one fresh process per point --------------------------------------

class WarningTally:
    """``warnings.showwarning`` counting the warnings by category, keeping
    the first message of each (a list of all would grow with the steps)."""

    def __init__(self):
        self.count, self.first = {}, {}

    def __call__(self, message, category, *args, **kwargs):
        name = category.__name__
        self.count[name] = self.count.get(name, 0) + 1
        self.first.setdefault(name, str(message))

    def summary(self):
        return sorted(f'{name} (x{n}): {self.first[name]}'
                      for name, n in self.count.items())


@contextlib.contextmanager
def tallied():
    """Every warning inside counted by the ``WarningTally`` yielded."""
    with warnings.catch_warnings():
        warnings.simplefilter('always')
        warnings.showwarning = tally = WarningTally()
        yield tally


def nose_memory_worker(steps):
    """One ReversibleNose point: run(N), then backpropagate(N) of a fixed
    random loss gradient (finite-difference Hessian-vector products)."""
    atoms = MEMORY_SYSTEM.atoms()
    dyn = reversible_nose(atoms, MEMORY_SYSTEM)
    start = dyn.counts
    rng = np.random.default_rng(LOSS_SEED)
    grad_x, grad_p = (rng.standard_normal((len(atoms), 3)),
                      rng.standard_normal((len(atoms), 3)))
    gc.collect()
    resident = [resident_bytes()]
    with tallied() as tally:
        tracemalloc.start()
        t0 = time.perf_counter()
        dyn.run(steps)
        t1 = time.perf_counter()
        forward_current, forward_peak = tracemalloc.get_traced_memory()
        resident.append(resident_bytes())
        tracemalloc.reset_peak()
        gradients = dyn.backpropagate(steps, grad_x, grad_p)
        t2 = time.perf_counter()
        current, peak = tracemalloc.get_traced_memory()
        tracemalloc.stop()
    resident.append(resident_bytes())
    end = dyn.counts
    gx_nc, gp_nc = gradients
    return {
        'steps': steps, 'atoms': len(atoms),
        'forward_traced_peak_bytes': forward_peak,
        'forward_traced_end_bytes': forward_current,
        'backpropagate_traced_peak_bytes': peak,
        'backpropagate_traced_end_bytes': current,
        'resident_bytes': resident,  # before, after run, after backpropagate
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


def measure_memory(lengths):
    # Longest first, so the workers finish together.
    raw = common.run_workers(Path(__file__), [
        (n,) for n in reversed(lengths.memory_steps)], MEMORY_PARALLEL)
    nose = sorted(raw, key=lambda r: r['steps'])
    system = MEMORY_SYSTEM
    return {'system': system.label, 'calculator': system.calculator,
            'n_atoms': nose[0]['atoms'],
            'temperature_K': system.temperature_K,
            'timestep_fs': system.timestep_fs,
            'parallel_workers': MEMORY_PARALLEL, 'nose': nose}


def run(quick):
    lengths = QUICK if quick else FULL
    speed = THERMOSTAT_SPEED[quick]
    # The machine is shared: the load around each part goes with it.
    load = {'start': os.getloadavg()}
    systems_ = [sampling_system(s, lengths) for s in SYSTEMS]
    load['before_memory'] = os.getloadavg()
    memory = measure_memory(lengths)
    load['before_cost'] = os.getloadavg()
    costs = [speed_case(s, r, speed, SPEED_CONTESTANTS, THERMOSTATS,
                        'ase_nose_hoover_chain')
             for s, r in (SPEED_CASES[:1] if quick else SPEED_CASES)]
    load['end'] = os.getloadavg()
    return {
        'load_average': load,
        'settings': {'start_factor': START_FACTOR,
                     'tdamp_steps': TDAMP_STEPS,
                     'langevin_friction_per_fs': FRICTION_PER_FS,
                     'langevin_seed': SEED,
                     'blocks': BLOCKS, 'window_c': WINDOW_C,
                     'force_every': FORCE_EVERY,
                     'temperature_goal_percent': TEMPERATURE_GOAL_PERCENT,
                     'ks_level': KS_LEVEL,
                     'potential_goal_standard_errors': POTENTIAL_GOAL_SE,
                     'memory_goal_ratio': MEMORY_GOAL_RATIO,
                     'cost_goal_ratio': COST_GOAL_RATIO,
                     'lengths_equilibration': lengths.equilibration,
                     'lengths_round_trip': lengths.round_trip,
                     'speed': asdict(speed)},
        'systems': systems_, 'memory': memory, 'speed': costs}


if __name__ == '__main__' and sys.argv[1:2] == ['--memory-worker']:
    print(json.dumps(nose_memory_worker(int(sys.argv[2]))), flush=True)
