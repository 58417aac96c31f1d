"""Run the benchmarks, then write ``docs/benchmarks.md`` with its plots.

Usage (from the repository root)::

    python benchmarks/run_all.py                    # the default sections, ~75 min
    python benchmarks/run_all.py --quick            # small cases, a few minutes
    python benchmarks/run_all.py --only step_cost   # one section (any of SECTIONS)
    python benchmarks/render.py                     # only render the stored results

Each section is a script of this directory with ``run(quick) -> dict``: it
measures and returns JSON-ready results, nothing else.  They are stored per
section in ``<out>/benchmarks/<name>.json`` with the command, date and
machine; then ``render.py`` rebuilds ``<out>/benchmarks.md`` and every plot
from all stored sections, so ``--only`` refreshes one section and keeps the
others.
"""

from __future__ import annotations

import common  # noqa: F401  (first: pins BLAS threads before numpy)

import argparse
import importlib
import json
import os
import sys
import time
from datetime import datetime
from pathlib import Path

import render

SECTIONS = render.SECTIONS
#: Measured by a plain run.  force_noise and long_reversal are diagnostics
#: kept out of it (long_reversal takes about an hour with ASE's
#: LennardJones), and so is npt_sampling (a 10^5-step run per integrator
#: and case, and the round trip back); torch_products and training need
#: the torch extra (training's 10^5-step memory point alone took 9
#: minutes); --only runs them, and the page shows them once stored.
DEFAULT_SECTIONS = ('step_cost', 'calculators', 'savings', 'work_precision',
                    'reversal_error', 'stress', 'gradient_accuracy',
                    'adjoint', 'thermostat', 'nose', 'npt_cost',
                    'lammps_cost',
                    'portable')


def measure(name, quick, only, machine) -> dict:
    """Run one section's measurement; the results with how they were made."""
    module = importlib.import_module(name)
    print(f'{name}:', flush=True)
    started = time.perf_counter()
    results = module.run(quick)
    stored = {
        'command': 'python benchmarks/run_all.py'
                   + (' --quick' if quick else '')
                   + (f' --only {name}' if only else ''),
        'date': datetime.now().astimezone().isoformat(timespec='seconds'),
        'quick': quick,
        'wall_seconds': time.perf_counter() - started,
        'load_average': os.getloadavg(),
        'machine': machine,
        'results': results,
    }
    print(f'  {stored["wall_seconds"]:.0f} s', flush=True)
    return stored


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--quick', action='store_true',
                        help='small cases and few repeats')
    parser.add_argument('--only', nargs='+', choices=SECTIONS,
                        help='run these sections, keep the others stored')
    parser.add_argument('--out', type=Path, default=common.DOCS,
                        help='directory of benchmarks.md (default: docs/)')
    args = parser.parse_args(argv)
    stored_dir = args.out / 'benchmarks'
    stored_dir.mkdir(parents=True, exist_ok=True)
    # Taken before anything runs: the package is imported once, so the
    # commit checked out now is the code every section measures.
    machine = common.machine_info()
    for name in args.only or DEFAULT_SECTIONS:
        stored = measure(name, args.quick, bool(args.only), machine)
        (stored_dir / f'{name}.json').write_text(json.dumps(stored, indent=1)
                                                 + '\n')
    print(f'Wrote {render.render(args.out)}')


if __name__ == '__main__':
    sys.exit(main())
