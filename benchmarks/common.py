"""Shared pieces of the benchmarks: thread settings, machine, timing.

Import this module before numpy (``run_all.py`` does): it pins BLAS to one
thread.  Some numpy calls on the MD path go to OpenBLAS threads (np.vdot in
Atoms.get_kinetic_energy, which MDLogger calls every step); on a busy
machine every hand-off waits for a scheduler time slice, milliseconds that
would swamp the per-step costs measured here.  Set the variables yourself
to override.
"""

from __future__ import annotations

import os

BLAS_THREAD_VARIABLES = ('OPENBLAS_NUM_THREADS', 'OMP_NUM_THREADS',
                         'MKL_NUM_THREADS')
#: The caller's environment: `nproc` honours OMP_NUM_THREADS, so the machine
#: description must not see the value set here.
CALLER_ENVIRONMENT = dict(os.environ)
for _name in BLAS_THREAD_VARIABLES:
    os.environ.setdefault(_name, '1')

import platform  # noqa: E402  (after the thread settings on purpose)
import subprocess  # noqa: E402
import warnings  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
DOCS = ROOT / 'docs'


def _run(command):
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
    commit = _run(['git', 'rev-parse', '--short', 'HEAD'])
    dirty = _run(['git', 'status', '--porcelain', '--untracked-files=no'])
    return {
        'cpu_model': cpu_model() or platform.processor() or '(not reported)',
        'uname': f'{uname.system} {uname.release} {uname.machine}',
        'nproc': _run(['nproc']) or str(os.cpu_count()),
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


def thermalised(atoms, temperature_K, seed=0):
    """Maxwell-Boltzmann momenta at exactly ``temperature_K`` (fixed seed)."""
    from ase.md.velocitydistribution import MaxwellBoltzmannDistribution
    # Deprecated in ASE 3.29, but a thin wrapper of thermalize_momenta,
    # which older ASE versions lack: same momenta, so keep it quiet.
    with warnings.catch_warnings():
        warnings.simplefilter('ignore', DeprecationWarning)
        MaxwellBoltzmannDistribution(atoms, temperature_K=temperature_K,
                                     rng=np.random.default_rng(seed),
                                     force_temp=True)
    return atoms


def markdown_table(header, rows) -> str:
    """A Markdown table from a header row and rows of cells."""
    lines = ['| ' + ' | '.join(map(str, header)) + ' |',
             '| ' + ' | '.join('---' for _ in header) + ' |']
    lines += ['| ' + ' | '.join(map(str, row)) + ' |' for row in rows]
    return '\n'.join(lines)


def pyplot():
    """matplotlib's pyplot on the non-interactive Agg backend."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    return plt
