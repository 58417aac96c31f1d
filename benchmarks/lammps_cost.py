"""ReversibleLammps, compiled and Python paths, against LAMMPS's own
``fix nve`` (and ``reversible nvt`` against ``fix nvt``), on 1 and 2 MPI
ranks, each case one ``mpiexec -n R python lammps_worker.py``
(``--only lammps_cost``: ~25 minutes, < 40 s with ``--quick``).
"""

from __future__ import annotations

import common

import json
import os
import statistics
import sys
import tempfile
from pathlib import Path

WORKER = Path(__file__).resolve().parent / 'lammps_worker.py'
TIMESTEP_PS = 0.001953125

#: The goal this section checks: the compiled exact path within this
#: factor of ``fix nve``'s time per step from this many atoms up.
GOAL_RATIO, GOAL_MIN_ATOMS = 1.03, 30_000
#: The same for ``reversible nvt`` against LAMMPS's ``fix nvt``.
GOAL_NVT_RATIO = 1.05

#: The instances of every case: LAMMPS's own integrator first, then the
#: exact ones measured against it (lammps_worker.INTEGRATORS).
INTEGRATORS = ('nve', 'compiled', 'python', 'nvt', 'exact_nvt')

#: (system, cells, ranks, steps per block, warm-up steps).
FULL_CASES = (
    ('argon', (10, 10, 10), 1, 300, 100),
    ('argon', (20, 20, 20), 1, 100, 50),
    ('argon', (20, 20, 20), 2, 100, 50),
    ('argon', (30, 30, 15), 1, 60, 40),
    ('argon', (30, 30, 30), 1, 60, 40),
    ('argon', (30, 30, 30), 2, 60, 40),
    ('argon', (40, 40, 40), 1, 20, 20),
    ('copper', (20, 20, 20), 1, 100, 50),
    ('copper', (20, 20, 20), 2, 100, 50),
    ('copper', (30, 30, 30), 1, 50, 30),
    ('copper', (30, 30, 30), 2, 50, 30),
)
QUICK_CASES = (
    ('argon', (10, 10, 10), 1, 20, 20),
    ('argon', (10, 10, 10), 2, 20, 20),
    ('copper', (10, 10, 10), 1, 20, 20),
    ('copper', (10, 10, 10), 2, 20, 20),
)
FULL = {'rounds': 6, 'setups': 5, 'reduce_blocks': 5, 'reduce_calls': 1000}
QUICK = {'rounds': 3, 'setups': 3, 'reduce_blocks': 3, 'reduce_calls': 1000}

LABELS = {'argon': 'Ar LJ', 'copper': 'Cu EAM'}


def run_case(case, log_dir) -> dict:
    """One case in ``mpiexec -n R python lammps_worker.py`` (the mpiexec
    installed beside this Python, the mpich wheel's)."""
    return common.run_worker(
        WORKER, [json.dumps(case), log_dir],
        [str(Path(sys.executable).parent / 'mpiexec'), '-n',
         str(case['ranks'])], timeout=1800)


def per_step_medians(blocks) -> dict:
    """Medians over blocks of what a step costs, in ms, and the counts."""
    def ms(seconds):
        return 1e3 * statistics.median(seconds(b) / b['steps'] for b in blocks)
    wall = [b['wall_seconds'] / b['steps'] for b in blocks]
    steps = sum(b['steps'] for b in blocks)
    clean = sum(b['clean_recomputations'] for b in blocks)
    return {
        **{f'{key}ms_per_step': ms(lambda b, k=key: b[f'{k or "wall_"}seconds'])
           for key in ('', 'cpu_', 'loop_')},
        'breakdown_ms_per_step': {
            s: ms(lambda b, s=s: b['breakdown_seconds'].get(s, 0.0))
            for s in sorted({k for b in blocks for k in b['breakdown_seconds']})},
        'spread': (max(wall) - min(wall)) / statistics.median(wall),
        'steps': steps, 'clean_recomputations': clean,
        'clean_per_step': clean / steps}


def long_run_medians(blocks, singles) -> dict:
    """What a step of a long run costs, in ms, with the cost of a run
    besides its steps removed: (median block of M - median block of one
    step) / (M - 1), in wall and CPU time; and that per-run cost."""
    steps = blocks[0]['steps']
    out = {}
    for key in ('wall', 'cpu'):
        many = statistics.median(b[f'{key}_seconds'] for b in blocks)
        one = statistics.median(b[f'{key}_seconds'] for b in singles)
        per_step = (many - one) / (steps - 1)
        out[f'{key}_ms_per_step'] = 1e3 * per_step
        out[f'{key}_ms_per_run'] = 1e3 * (one - per_step)
    return out


def run(quick):
    settings = QUICK if quick else FULL
    cases = []
    with tempfile.TemporaryDirectory() as log_dir:
        for system, cells, ranks, steps, warmup in (
                QUICK_CASES if quick else FULL_CASES):
            case = {'system': system, 'cells': list(cells), 'ranks': ranks,
                    'integrators': list(INTEGRATORS), 'steps': steps,
                    'warmup_steps': warmup, **settings}
            natoms = 4 * cells[0] * cells[1] * cells[2]
            label = f'{LABELS[system]} {natoms}, {ranks} rank' + (
                's' if ranks > 1 else '')
            load = os.getloadavg()
            print(f'  {label} (load average {load[0]:.2f})', flush=True)
            measured = run_case(case, log_dir)
            measured['load_average'] = [load, os.getloadavg()]
            assert measured['natoms'] == natoms and measured['ranks'] == ranks
            cases.append({
                'label': label, **case, **measured,
                'median': {name: per_step_medians(blocks) for name, blocks
                           in measured['blocks'].items()},
                'long_run': {name: long_run_medians(
                    blocks, measured['single_step_blocks'][name])
                    for name, blocks in measured['blocks'].items()}})
    return {'cpu': common.cpu_model(),
            'cores': common.command_output(['nproc']),
            'timestep_ps': TIMESTEP_PS,
            'goal_ratio': GOAL_RATIO, 'goal_min_atoms': GOAL_MIN_ATOMS,
            'goal_ratios': {'compiled': GOAL_RATIO,
                            'exact_nvt': GOAL_NVT_RATIO},
            'cases': cases}
