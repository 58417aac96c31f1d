"""The compiled fix at 256,000 and 10^6 atoms (``--only lammps_scale``:
~20 minutes; stored as the lammps_cost section's 'scale').

Two measurements, on 1 and 2 ranks of this machine:

- the compiled fix against ``fix nve``, CPU time per step of a long run
  (lammps_cost's method: interleaved blocks, the per-run cost removed by
  single-step blocks), argon at 256,000 and 1,000,188 atoms;
- 10^6 argon atoms out and back on 2 ranks from the default grid (held at
  its 10^5-atom resolution): the steps whose flagged kicks were recomputed,
  each on the rank holding the atom, their wall time against the run's,
  and whether every atom landed on its start bit for bit.
"""

from __future__ import annotations

import common  # noqa: F401  (first: pins BLAS threads before numpy)

import os
import tempfile

from lammps_cost import long_run_medians, per_step_medians, run_case

#: (cells, ranks, steps per block, warm-up steps): 4 atoms per cell.
FULL_CASES = (((40, 40, 40), 1, 20, 10), ((40, 40, 40), 2, 20, 10),
              ((63, 63, 63), 1, 8, 4), ((63, 63, 63), 2, 8, 4))
QUICK_CASES = (((20, 20, 20), 1, 10, 5), ((20, 20, 20), 2, 10, 5))
FULL = {'rounds': 4, 'setups': 3, 'reduce_blocks': 1, 'reduce_calls': 10}
QUICK = {'rounds': 2, 'setups': 2, 'reduce_blocks': 1, 'reduce_calls': 10}
#: The run out and back: (cells, ranks, steps).
FULL_REVERSAL = ((63, 63, 63), 2, 200)
QUICK_REVERSAL = ((20, 20, 20), 2, 50)


def run(quick):
    settings = QUICK if quick else FULL
    costs = []
    with tempfile.TemporaryDirectory() as log_dir:
        for cells, ranks, steps, warmup in (QUICK_CASES if quick
                                             else FULL_CASES):
            case = {'system': 'argon', 'cells': list(cells), 'ranks': ranks,
                    'integrators': ['nve', 'compiled'], 'steps': steps,
                    'warmup_steps': warmup, **settings}
            load = os.getloadavg()
            print(f'  argon {4 * cells[0] * cells[1] * cells[2]:,}, {ranks} '
                  f'rank(s) (load average {load[0]:.2f})', flush=True)
            measured = run_case(case, log_dir)
            measured['load_average'] = [load, os.getloadavg()]
            costs.append({
                **case, **measured,
                'median': {name: per_step_medians(blocks) for name, blocks
                           in measured['blocks'].items()},
                'long_run': {name: long_run_medians(
                    blocks, measured['single_step_blocks'][name])
                    for name, blocks in measured['blocks'].items()}})
        cells, ranks, steps = QUICK_REVERSAL if quick else FULL_REVERSAL
        print(f'  argon {4 * cells[0] * cells[1] * cells[2]:,} out and back, '
              f'{ranks} ranks', flush=True)
        reversal = run_case({'job': 'reversal', 'system': 'argon',
                             'cells': list(cells), 'ranks': ranks,
                             'steps': steps}, log_dir)
    return {'costs': costs, 'reversal': reversal}
