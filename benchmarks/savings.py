"""Per-step cost of the package at several commits, each exported with
``git archive`` into a worker process of its own (``--worker``), timed side
by side in rotating rounds; a commit missing from the clone is skipped."""

from __future__ import annotations

import common

import io
import pickle
import statistics
import subprocess
import sys
import tarfile
import tempfile
import time
from pathlib import Path

#: (commit, what it changed).  The first is the baseline.
COMMITS = (
    ('c938961', 'before: a new array per update, decode per sub-step'),
    ('64e3cbb', 'rotating buffers, one rounding per kick, in-place writes'),
    ('6747469', "asap3's list updated without a force call far away"),
    ('dfceefa', 'the half kick reused; range checks on a running bound'),
    ('9082669', 'the energy check (steps 1, 2, 4, ..., then every 100)'),
    ('d48a84e', "guard bound scaled with the coordinates' extent"),
    ('bedad94', 'before the engine rewrite: the integrator as one class'),
)
#: (label, steps per block in the full and the quick run; None: not run).
CASES = (
    ('Cu 4000 asap3 EMT', (100, 20)),
    ('Cu 32000 asap3 EMT', (12, None)),
    ('Ar 4000 asap3 LJ', (100, None)),
    ('Ar147 ASE LJ', (100, 20)),
)
TIMESTEP_FS = 5.0
WARMUP_STEPS = 5


def build(label):
    """Atoms and something that gives a fresh calculator, for a case.

    Imported here, not at the top: the workers run this script with an old
    commit's package, which has no ``ase_reversible.app``.
    """
    import asap3
    import systems
    from ase_reversible.app import systems as app_systems
    if label == 'Cu 4000 asap3 EMT':
        return app_systems.copper_bulk(10, 300, rattle=0), asap3.EMT
    if label == 'Cu 32000 asap3 EMT':
        return app_systems.copper_bulk(20, 300, rattle=0), asap3.EMT
    if label == 'Ar 4000 asap3 LJ':
        return app_systems.argon_bulk(10, 60), systems.asap3_argon_lj()
    if label == 'Ar147 ASE LJ':
        # An ASE calculator pickles as it is; asap3's only as a constructor.
        return app_systems.argon_cluster(4, 60), app_systems.argon_lj()
    raise ValueError(label)


def worker(source, case_file):
    """Run blocks of steps on request: a line with a number of steps on
    stdin, a line with the seconds they took on stdout."""
    from ase import units

    import ase_reversible
    from ase_reversible import ReversibleVerlet
    assert ase_reversible.__file__.startswith(source), ase_reversible.__file__
    atoms, calc = pickle.loads(Path(case_file).read_bytes())
    atoms.calc = calc() if callable(calc) else calc
    dyn = ReversibleVerlet(atoms, TIMESTEP_FS * units.fs)
    dyn.run(WARMUP_STEPS)
    print('ready', flush=True)
    for line in sys.stdin:
        steps = int(line)
        start = time.perf_counter()
        dyn.run(steps)
        print(time.perf_counter() - start, flush=True)


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
    head = common.command_output(['git', 'rev-parse', '--short', 'HEAD'])
    dirty = common.command_output(['git', 'status', '--porcelain',
                                   '--untracked-files=no', 'ase_reversible'])
    return head, bool(dirty)


def time_case(label, steps, sources, quick, case_file):
    workers = {}
    for name, path in sources.items():
        workers[name] = subprocess.Popen(
            [sys.executable, __file__, '--worker', str(path), str(case_file)],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True,
            env={**common.os.environ, 'PYTHONPATH': str(path)})
        assert workers[name].stdout.readline().strip() == 'ready'
    names = list(workers)
    samples = {name: [] for name in names}
    rounds = 3 if quick else 15
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


def run(quick):
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
        for label, (full_steps, quick_steps) in CASES:
            steps = quick_steps if quick else full_steps
            if steps is None:
                continue
            print(f'  {label}', flush=True)
            case_file = Path(tmp) / 'case.pickle'
            case_file.write_bytes(pickle.dumps(build(label)))
            results['cases'].append(time_case(label, steps, sources, quick,
                                              case_file))
    return results


if __name__ == '__main__' and sys.argv[1:2] == ['--worker']:
    worker(*sys.argv[2:4])
