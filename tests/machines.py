"""Other machines, emulated in subprocesses, for the tests that cross them.

A user's run may be written on one CPU and continued or run back on
another.  The last bits of some floating-point results differ between
them: numpy dispatches its loops for ``exp``, ``log``, ``power``, ``cbrt``
and ``tanh`` to SIMD code chosen for the CPU at import time (AVX-512, AVX2
or SSE), and OpenBLAS picks its kernels by core type.  Measured on the
2-core AMD EPYC (Zen 4, AVX-512) that this suite was written on, numpy 2.4:
``np.exp``, ``np.log``, ``x**6``, ``x**-1.5`` and ``np.cbrt`` of 10^5
numbers changed bits with ``X86_V4`` dispatch switched off, ``np.tanh``
with ``X86_V3`` off too, and a 3x300 @ 300x3 product and ``np.vdot`` with
every other ``OPENBLAS_CORETYPE``; ``+ - * /``, ``sqrt``, ``np.sum``,
``np.einsum``, ``np.bincount`` and ``sin``/``cos`` did not change.

So a "machine" here is the environment of a subprocess: which of numpy's
dispatch targets are switched off (``NPY_DISABLE_CPU_FEATURES``, only
those this numpy build dispatches to, so that it starts on any CPU) and
which OpenBLAS core type it runs.  No CPU's bits are recorded: a test
runs one leg of a computation on one machine and the next leg on
another, and compares the two within the same test run.
"""

import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

#: name -> (numpy dispatch targets switched off, OpenBLAS core type).
#: ``native`` is this CPU as it is.
MACHINES = {
    'native': ((), None),
    'avx2': (('X86_V4', 'AVX512_ICL', 'AVX512_SPR'), 'Haswell'),
    'sse4': (('X86_V3', 'X86_V4', 'AVX512_ICL', 'AVX512_SPR'), 'Prescott'),
}


def _dispatched():
    try:
        from numpy._core._multiarray_umath import __cpu_dispatch__
    except ImportError:  # numpy 1.x
        from numpy.core._multiarray_umath import __cpu_dispatch__
    return set(__cpu_dispatch__)


def machine_env(name):
    """The environment of a subprocess that computes as machine ``name``
    would: this process's environment, the package importable from this
    checkout, and numpy's dispatch and OpenBLAS's core type set."""
    disabled, coretype = MACHINES[name]
    env = dict(os.environ)
    env['PYTHONPATH'] = os.pathsep.join(
        [str(ROOT)] + [p for p in [env.get('PYTHONPATH')] if p])
    env.pop('NPY_DISABLE_CPU_FEATURES', None)
    # ``native`` keeps a core type the machine's environment sets (some
    # set one because older OpenBLAS builds misbehave on their CPU).
    off = [feature for feature in disabled if feature in _dispatched()]
    if off:
        env['NPY_DISABLE_CPU_FEATURES'] = ' '.join(off)
    if coretype is not None:
        env['OPENBLAS_CORETYPE'] = coretype
    return env


def run_leg(machine, script, cwd, timeout=300):
    """Run the Python source ``script`` in a subprocess as ``machine``, in
    the folder ``cwd`` (legs hand each other files there); returns what it
    printed.  A leg that fails fails the test with its own traceback."""
    done = subprocess.run([sys.executable, '-c', script], cwd=cwd,
                          env=machine_env(machine), capture_output=True,
                          text=True, timeout=timeout)
    assert done.returncode == 0, (
        f'leg on machine {machine!r} failed:\n{done.stdout}\n{done.stderr}')
    return done.stdout


def bits_of(machine, expression, cwd):
    """The bytes of a numpy expression (of ``np`` and a fixed random
    array ``x``), computed on ``machine``, as hex."""
    script = ('import numpy as np\n'
              'x = np.random.default_rng(0).uniform(0.5, 3.0, (300, 3))\n'
              f'print(np.ascontiguousarray({expression}).tobytes().hex())\n')
    return run_leg(machine, script, cwd).strip()


def emulation_works(cwd):
    """Whether the machines differ at all on this one: a BLAS product
    always does (OpenBLAS's core types), numpy's dispatch where this CPU
    has what is switched off."""
    native = bits_of('native', 'x.T @ x', cwd)
    return native != bits_of('sse4', 'x.T @ x', cwd)

