"""Before and after: per-step cost of the package at two or more commits.

Each commit's ``ase_reversible`` is exported with ``git archive`` into a
temporary directory and imported by a worker process of its own.  Every
worker builds the same thermalised system with the same calculator; the
parent then asks the workers for blocks of steps in rounds, rotating their
order, and compares medians, so the commits are timed side by side under
the same machine load.  The commits are the steps of the work that made the
per-step path cheaper (listed in ``COMMITS``); a commit missing from the clone (a shallow
clone) is reported as skipped.
"""

from __future__ import annotations

import common

import io
import json
import statistics
import subprocess
import sys
import tarfile
import tempfile
from pathlib import Path

#: (commit, what it changed).  The first is the baseline.
COMMITS = (
    ('c938961', 'before: a new array per update, decode per sub-step'),
    ('64e3cbb', 'rotating buffers, one rounding per kick, in-place writes'),
    ('6747469', "asap3's list updated without a force call far away"),
    ('dfceefa', 'the half kick reused; range checks on a running bound'),
    ('9082669', 'the energy check (steps 1, 2, 4, ..., then every 100)'),
    ('d48a84e', "guard bound scaled with the coordinates' extent"),
)

#: (label, builder expression for the worker, steps per block (full, quick)).
CASES = (
    ('Cu 4000 asap3 EMT', "bulk('Cu', 'fcc', a=3.6, cubic=True) * 10",
     'asap3.EMT()', (100, 20)),
    ('Cu 32000 asap3 EMT', "bulk('Cu', 'fcc', a=3.6, cubic=True) * 20",
     'asap3.EMT()', (12, None)),
    ('Ar 4000 asap3 LJ', "bulk('Ar', 'fcc', a=5.26, cubic=True) * 10",
     "asap3.LennardJones([18], [0.0104], [3.4], rCut=8.5, modified=True)",
     (100, None)),
    ('Ar147 ASE LJ', "_icosahedron()",
     "LennardJones(sigma=3.4, epsilon=0.0104, rc=8.5)", (100, 20)),
)

WORKER = r'''
import os, sys, time
for name in ('OPENBLAS_NUM_THREADS', 'OMP_NUM_THREADS', 'MKL_NUM_THREADS'):
    os.environ.setdefault(name, '1')
import numpy as np, asap3
from ase import units
from ase.build import bulk
from ase.calculators.lj import LennardJones
from ase.cluster import Icosahedron
from ase.md.velocitydistribution import MaxwellBoltzmannDistribution
import ase_reversible
from ase_reversible import ReversibleVerlet
assert ase_reversible.__file__.startswith(sys.argv[1]), ase_reversible.__file__
def _icosahedron():
    atoms = Icosahedron('Ar', 4, latticeconstant=5.26)
    atoms.center(vacuum=10.0)
    return atoms
atoms = eval(sys.argv[2])
MaxwellBoltzmannDistribution(atoms, temperature_K=300 if atoms[0].symbol == 'Cu' else 60,
                             rng=np.random.default_rng(0), force_temp=True)
atoms.calc = eval(sys.argv[3])
dyn = ReversibleVerlet(atoms, 5 * units.fs)
dyn.run(5)
print('ready', flush=True)
for line in sys.stdin:
    steps = int(line)
    start = time.perf_counter()
    dyn.run(steps)
    print(time.perf_counter() - start, flush=True)
'''


def export(commit, into: Path) -> bool:
    """Put ``ase_reversible`` of ``commit`` under ``into``; False if missing."""
    try:
        tar = subprocess.run(['git', 'archive', commit, 'ase_reversible'],
                             cwd=common.ROOT, capture_output=True, check=True)
    except (OSError, subprocess.CalledProcessError):
        return False
    with tarfile.open(fileobj=io.BytesIO(tar.stdout)) as archive:
        archive.extractall(into, filter='data')
    return True


def head_commits():
    head = common._run(['git', 'rev-parse', '--short', 'HEAD'])
    dirty = common._run(['git', 'status', '--porcelain',
                         '--untracked-files=no', 'ase_reversible'])
    return head, bool(dirty)


def time_case(case, sources, quick):
    label, build, calc, (full_steps, quick_steps) = case
    steps = quick_steps if quick else full_steps
    workers = {}
    for name, path in sources.items():
        proc = subprocess.Popen(
            [sys.executable, '-c', WORKER, str(path), build, calc],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True,
            # `python -c` puts the working directory first on sys.path.
            cwd=path, env={**common.os.environ, 'PYTHONPATH': str(path)})
        assert proc.stdout.readline().strip() == 'ready'
        workers[name] = proc
    names = list(workers)
    samples = {name: [] for name in names}
    rounds = 3 if quick else 7
    try:
        for r in range(rounds):
            for name in names[r % len(names):] + names[:r % len(names)]:
                proc = workers[name]
                proc.stdin.write(f'{steps}\n')
                proc.stdin.flush()
                samples[name].append(float(proc.stdout.readline()) / steps)
    finally:
        for proc in workers.values():
            proc.stdin.close()
            proc.wait()
    medians = {name: statistics.median(v) for name, v in samples.items()}
    return {'case': label, 'steps_per_block': steps, 'rounds': rounds,
            'ms_per_step': {n: 1e3 * m for n, m in medians.items()},
            'spread': max((max(v) - min(v)) / statistics.median(v)
                          for v in samples.values())}


def run(quick, figures):
    head, dirty = head_commits()
    listed = [c for c, _ in COMMITS]
    results = {'commits': [{'commit': c, 'change': what}
                           for c, what in COMMITS], 'cases': [], 'skipped': []}
    with tempfile.TemporaryDirectory() as tmp:
        sources = {}
        for commit in listed:
            path = Path(tmp) / commit
            if export(commit, path):
                sources[commit] = path
            else:
                results['skipped'].append(commit)
        if dirty or not any(head and c.startswith(head[:7]) for c in listed):
            label = f'{head} + local changes' if dirty else head
            results['commits'].append({'commit': label,
                                       'change': 'this version'})
            sources[label] = common.ROOT
        if len(sources) < 2:
            return results
        for case in CASES:
            if (case[3][1] if quick else case[3][0]) is None:
                continue
            print(f'  {case[0]}', flush=True)
            results['cases'].append(time_case(case, sources, quick))
    return results


TITLE = 'Savings on the per-step path'


def render(results):
    if not results['cases']:
        return ('Skipped: the baseline commits '
                f"{', '.join(results['skipped'])} are not in this clone.")
    commits = [c['commit'] for c in results['commits']
               if c['commit'] not in results['skipped']]
    rows = []
    for case in results['cases']:
        base = case['ms_per_step'][commits[0]]
        rows.append([case['case']] + [
            f"{case['ms_per_step'][c]:.3f} ({case['ms_per_step'][c] / base:.3f})"
            for c in commits] + [f"{case['spread']:.0%}"])
    changes = '\n'.join(f"- `{c['commit']}`: {c['change']}"
                        for c in results['commits'])
    return f"""The package at each commit below runs in a worker process of its own
on the same system; blocks of steps are interleaved between the workers in
rotating order and the medians compared (`benchmarks/savings.py`).
Default settings (`scheme='velocity'`, `force_purity='auto'`, 5 fs).

{changes}

ms per step (ratio to the first commit):

{common.markdown_table(['case'] + commits + ['round spread'], rows)}
"""


if __name__ == '__main__':
    print(json.dumps(run('--quick' in sys.argv, None), indent=1))
