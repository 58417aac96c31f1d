"""Thread settings, the package measured, the machine.

Import this module before numpy: it pins BLAS to one thread (on a busy
machine each hand-off to an OpenBLAS thread, e.g. np.vdot in MDLogger's
kinetic energy, waits milliseconds for a time slice); set the variables to
override.  It puts this checkout ahead of an installed ``ase_reversible``
(the commit recorded must be the code measured), behind PYTHONPATH's
entries (how savings.py points its workers at other commits).
"""

from __future__ import annotations

import os
import sys

BLAS_THREAD_VARIABLES = ('OPENBLAS_NUM_THREADS', 'OMP_NUM_THREADS',
                         'MKL_NUM_THREADS')
#: The caller's environment (`nproc` honours OMP_NUM_THREADS).
CALLER_ENVIRONMENT = dict(os.environ)
for _name in BLAS_THREAD_VARIABLES:
    os.environ.setdefault(_name, '1')

import platform  # noqa: E402  (after the thread settings on purpose)
import subprocess  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
DOCS = ROOT / 'docs'

if str(ROOT) not in sys.path:
    # sys.path[0] is the script's directory, then come PYTHONPATH's entries.
    _python_path = [p for p in os.environ.get('PYTHONPATH', '').split(
        os.pathsep) if p]
    sys.path.insert(1 + len(_python_path), str(ROOT))


def command_output(command):
    """Stripped stdout of ``command`` run in the checkout, or None."""
    try:
        return subprocess.run(command, capture_output=True, text=True,
                              check=True, cwd=ROOT,
                              env=CALLER_ENVIRONMENT).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return None


def cpu_model():
    try:
        with open('/proc/cpuinfo') as f:
            for line in f:
                if line.startswith('model name'):
                    return line.split(':', 1)[1].strip()
    except OSError:
        pass
    return None


def machine_info() -> dict:
    """What the numbers were measured on: hardware, versions, commit."""
    import ase
    import asap3
    import ase_reversible
    uname = platform.uname()
    commit = command_output(['git', 'rev-parse', '--short', 'HEAD'])
    dirty = command_output(['git', 'status', '--porcelain',
                            '--untracked-files=no'])
    return {
        'cpu_model': cpu_model() or platform.processor() or '(not reported)',
        'uname': f'{uname.system} {uname.release} {uname.machine}',
        'nproc': command_output(['nproc']) or str(os.cpu_count()),
        'python': platform.python_version(),
        'numpy': np.__version__,
        'ase': ase.__version__,
        'asap3': asap3.__version__,
        'ase_reversible': ase_reversible.__version__,
        'git_commit': (commit + ('+local changes' if dirty else '')
                       if commit else None),
        'blas_threads': ', '.join(f'{name}={os.environ.get(name)}'
                                  for name in BLAS_THREAD_VARIABLES),
    }


def run_workers(script, jobs, parallel=2) -> list:
    """``run_worker(script, ['--memory-worker', *job])`` of each job, at most
    ``parallel`` at a time; the results in the order of ``jobs``."""
    from concurrent.futures import ThreadPoolExecutor
    with ThreadPoolExecutor(parallel) as pool:
        return list(pool.map(
            lambda job: run_worker(script, ['--memory-worker', *job]), jobs))


def run_worker(script, args, launcher=(), timeout=None) -> dict:
    """The JSON object of the last line ``[*launcher] python script *args``
    prints in a fresh process (memory from a clean start), within
    ``timeout`` seconds, with its wall time as ``'process_seconds'``."""
    import json
    import time
    here = str(Path(__file__).resolve().parent)
    path = os.pathsep.join(p for p in (here, os.environ.get('PYTHONPATH'))
                           if p)
    started = time.perf_counter()
    proc = subprocess.run(
        [*launcher, sys.executable, str(script), *map(str, args)],
        capture_output=True, text=True, cwd=ROOT, timeout=timeout,
        env={**os.environ, 'PYTHONPATH': path})
    if proc.returncode != 0:
        raise RuntimeError(f'worker {Path(script).name} {args} failed:\n'
                           + proc.stderr[-3000:])
    result = json.loads(proc.stdout.strip().splitlines()[-1])
    result['process_seconds'] = time.perf_counter() - started
    return result
