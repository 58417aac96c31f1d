"""Exact reversible MD on LAMMPS across MPI ranks.

:class:`ReversibleLammps` runs the exact integrator inside a LAMMPS
instance, every rank on its own atoms; :mod:`.script` runs a LAMMPS input
script with it (``mpiexec -n 2 python -m ase_reversible.lammps in.file``).
Importing this package does not import LAMMPS.
"""

from .integrator import ReversibleLammps
from .mpi import finalize_mpi, import_lammps
from .nose import ReversibleLammpsNose

__all__ = ['ReversibleLammps', 'ReversibleLammpsNose', 'finalize_mpi',
           'import_lammps']
