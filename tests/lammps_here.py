"""One-rank LAMMPS runs of the tests in the test's own process.

Starting a process for a run costs about 0.7 s, most of it importing, and
the quick tier has dozens of one-rank runs.  :func:`run_here` runs what
``test_lammps.launch(1, ...)`` would (a worker script of these tests, or
``-m ase_reversible.lammps``) in this process instead, on a new LAMMPS
instance as the process would make, and returns the same exit status and
output.  Runs on more ranks, and those that need a process of their own
(environment variables that decide the compiled step's build: this process
may have loaded the plugin already), are still launched.  This relies on
``finalize_mpi`` (which the script runner calls) leaving MPI running on
one rank: a process cannot start MPI again once it has ended it.
"""

import contextlib
import ctypes
import importlib
import io
import os
import subprocess
import sys
import tempfile
from pathlib import Path

from conftest import needs_lammps


def run_here(*args, cwd=None):
    """``args`` (a worker script of these tests and its arguments, or
    ``'-m', 'ase_reversible.lammps'`` and the script runner's) run in this
    process, in ``cwd``: a CompletedProcess of the exit status, standard
    output and error.  An exception a worker raises is raised here."""
    needs_lammps()
    args = [str(arg) for arg in args]
    if args[:2] == ['-m', 'ase_reversible.lammps']:
        from ase_reversible.lammps.script import main

        def run():
            return main(args[2:])
    else:
        worker = importlib.import_module(Path(args[0]).stem)

        def run():
            worker.main(args[1], args[2],
                        **dict(arg.split('=', 1) for arg in args[3:]))
            return 0
    with captured(cwd) as done:
        done.returncode = run()
    return done


@contextlib.contextmanager
def captured(cwd=None):
    """In ``cwd``, what Python and the C library (LAMMPS writes its screen
    output through stdio) print, into the ``stdout`` and ``stderr`` of the
    CompletedProcess yielded; printed again on the way out of an
    exception, for pytest to show."""
    done = subprocess.CompletedProcess([], None, '', '')
    libc = ctypes.CDLL(None)
    here = Path.cwd()
    python = io.StringIO(), io.StringIO()
    with tempfile.TemporaryFile('w+', errors='replace') as out, \
            tempfile.TemporaryFile('w+', errors='replace') as err:
        libc.fflush(None)  # what is pending goes where it was written
        saved = os.dup(1), os.dup(2)
        os.dup2(out.fileno(), 1)
        os.dup2(err.fileno(), 2)
        failed = True
        try:
            if cwd is not None:
                os.chdir(cwd)
            with contextlib.redirect_stdout(python[0]), \
                    contextlib.redirect_stderr(python[1]):
                yield done
            failed = False
        finally:
            libc.fflush(None)
            os.dup2(saved[0], 1)
            os.dup2(saved[1], 2)
            os.close(saved[0])
            os.close(saved[1])
            os.chdir(here)
            for file in out, err:
                file.seek(0)
            done.stdout = out.read() + python[0].getvalue()
            done.stderr = err.read() + python[1].getvalue()
            if failed:
                print(done.stdout)
                print(done.stderr, file=sys.stderr)
