"""Run the benchmarks, then write ``docs/benchmarks.md`` with its plots.

    python benchmarks/run_all.py                    # the default sections, ~75 min
    python benchmarks/run_all.py --quick            # small cases, a few minutes
    python benchmarks/run_all.py --only step_cost   # sections or studies

Each section is a script here (or in ``studies/``) whose ``run(quick)``
returns JSON-ready results, stored in ``<out>/benchmarks/<name>.json`` with
the command, date and machine; ``render.py`` then rebuilds the pages from
every stored section.  A study is stored inside its section's results, and
a run of the section keeps it.
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

sys.path.insert(1, str(Path(__file__).resolve().parent / 'studies'))

SECTIONS = render.SECTIONS
#: Measured by a plain run; the others (diagnostics, hour-long runs, the
#: torch extra) only by --only.
DEFAULT_SECTIONS = ('step_cost', 'calculators', 'savings', 'work_precision',
                    'reversal_error', 'stress', 'gradient_accuracy',
                    'adjoint', 'thermostat', 'nose', 'npt_cost',
                    'lammps_cost', 'portable')
#: Study -> (module, its function of ``quick``, section, key in the
#: section's results, key of its record there: None for beside them).
STUDIES = {'nose_timestep': ('nose_timestep', 'run', 'nose', 'timestep', None),
           'nose_chain': ('nose_chain', 'run', 'nose', 'chain', None),
           'training_memory': ('training', 'measure_memory', 'training',
                               'memory', 'measured'),
           'device_neighbours': ('device_neighbours', 'run', 'gpu',
                                 'neighbours', None),
           'lammps_scale': ('lammps_scale', 'run', 'lammps_cost', 'scale',
                            None),
           'rigid_sampling': ('rigid_sampling', 'run', 'rigid', 'sampling',
                              None),
           'rigid_stability': ('rigid_stability', 'run', 'rigid',
                               'stability', None)}


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


def stored_section(section, stored_dir):
    """``section``'s JSON in ``stored_dir``, else in docs/benchmarks/, else
    None."""
    for directory in (stored_dir, common.DOCS / 'benchmarks'):
        path = directory / f'{section}.json'
        if path.exists():
            return json.loads(path.read_text())
    return None


def measure_study(name, quick, stored_dir, machine) -> tuple:
    """Run one study: its section's name and stored JSON with it in place."""
    module, function, section, key, record_key = STUDIES[name]
    stored = stored_section(section, stored_dir)
    print(f'{name}:', flush=True)
    started, load = time.perf_counter(), os.getloadavg()
    results = getattr(importlib.import_module(module), function)(quick)
    record = {'command': f'python benchmarks/run_all.py --only {name}'
                         + (' --quick' if quick else ''),
              'date': datetime.now().astimezone().isoformat(
                  timespec='seconds')}
    if record_key is None:
        record.update(git_commit=machine['git_commit'],
                      wall_seconds=time.perf_counter() - started,
                      load_average={'start': load, 'end': os.getloadavg()})
        results.update(record)
    else:
        results[record_key] = {**record,
                               'wall_seconds': time.perf_counter() - started,
                               'load_average': os.getloadavg()}
    stored['results'][key] = results
    return section, stored


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--quick', action='store_true',
                        help='small cases and few repeats')
    parser.add_argument('--only', nargs='+', choices=SECTIONS + tuple(STUDIES),
                        help='run these sections or studies, keep the others '
                             'stored')
    parser.add_argument('--out', type=Path, default=common.DOCS,
                        help='directory of benchmarks.md (default: docs/)')
    args = parser.parse_args(argv)
    stored_dir = args.out / 'benchmarks'
    stored_dir.mkdir(parents=True, exist_ok=True)
    # Before anything runs: the commit now is the code every section measures.
    machine = common.machine_info()
    for name in args.only or DEFAULT_SECTIONS:
        if name in STUDIES:
            name, stored = measure_study(name, args.quick, stored_dir,
                                         machine)
        else:
            before = stored_section(name, stored_dir) or {'results': {}}
            stored = measure(name, args.quick, bool(args.only), machine)
            # A section's run keeps the studies stored inside it.
            for _, _, section, key, _ in STUDIES.values():
                if section == name and key in before['results']:
                    stored['results'].setdefault(key, before['results'][key])
        (stored_dir / f'{name}.json').write_text(json.dumps(stored, indent=1)
                                                 + '\n')
    print(f'Wrote {render.render(args.out)}')


if __name__ == '__main__':
    sys.exit(main())
