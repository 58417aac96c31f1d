"""Cost per step of ReversibleIsotropicNPT against ASE's IsotropicMTKNPT
on the cases of npt_sampling at several sizes
(``--only npt_cost``: ~10 minutes, < 60 s with ``--quick``).
"""

from __future__ import annotations

import common  # noqa: F401  (first: pins BLAS threads before numpy)

import os
from dataclasses import asdict

from harness import (Contestant, choose_steps, medians, per_step,
                     time_interleaved)
from systems import NPT_CASES as CASES
from systems import NPT_INTEGRATORS as INTEGRATORS
from systems import THERMOSTAT_SPEED

#: (case of systems.NPT_CASES, repeat) of the cost measurement.
COST_CASES = ((CASES[0], (4, 4, 4)), (CASES[0], (5, 5, 5)),
              (CASES[0], (8, 8, 8)), (CASES[2], (4, 4, 4)),
              (CASES[2], (6, 6, 6)))
QUICK_COST_CASES = (COST_CASES[0], COST_CASES[3])
#: The goal judged on the page: ReversibleIsotropicNPT over ASE's.
RATIO_GOAL = 1.1


def cost_case(case, repeat, settings, names):
    """Interleaved per-step times of ``names`` on copies of one start."""
    contestants = []
    for name in names:
        label, atoms = case.atoms(repeat)
        contestants.append(Contestant(name, INTEGRATORS[name](atoms, case)))
    for c in contestants:
        c.runner.run(settings.warmup_steps)
    steps = choose_steps(contestants[-1].runner.run, settings)
    wall, cpu = time_interleaved(contestants, steps, settings.rounds)
    median, median_cpu = medians(wall), medians(cpu)
    result = {
        'label': case.label, 'calculator': label,
        'n_atoms': len(contestants[0].runner.atoms),
        'timestep_fs': case.timestep_fs,
        'steps_per_block': steps, 'rounds': settings.rounds,
        **per_step(wall, cpu),
        'ratio': median['reversible_npt'] / median['ase_npt'],
        'ratio_cpu': median_cpu['reversible_npt'] / median_cpu['ase_npt']}
    print(f"  {label:10s} N={result['n_atoms']:5d} S={steps:4d}  "
          + '  '.join(f'{k}={v * 1e6:.0f}µs' for k, v in median.items())
          + f"  ratio {result['ratio']:.3f}", flush=True)
    return result


def run(quick):
    settings = THERMOSTAT_SPEED[quick]
    cases = QUICK_COST_CASES if quick else COST_CASES
    names = tuple(INTEGRATORS)
    load = {'start': os.getloadavg()}
    costs = [cost_case(case, repeat, settings, names)
             for case, repeat in cases]
    load['end'] = os.getloadavg()
    return {'load_average': load,
            'settings': {**asdict(settings), 'ratio_goal': RATIO_GOAL},
            'costs': costs}

