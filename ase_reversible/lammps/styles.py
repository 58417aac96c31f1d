"""Which LAMMPS styles exact runs take: the unit styles the guard's bound
was measured in, the fixes that leave the motion to the exact integrator,
and the pair styles and long-range solvers whose forces are a function of
the positions within that bound."""

from __future__ import annotations

import os
import re
import tempfile
from pathlib import Path

#: Unit styles whose force and distance scales the noise bound assumes
#: (forces of order 1, coordinates of order 10 to 1000).
SUPPORTED_UNITS = ('metal', 'real', 'lj')

#: Fix styles that only add to or set forces, or only observe: the
#: motion stays the exact integrator's.  Any other fix is refused before
#: a run (LAMMPS's all-capital styles are its own internal fixes).
PASSIVE_FIXES = frozenset('''
    addforce aveforce setforce gravity efield spring spring/self
    spring/couple spring/rg indent lineforce planeforce enforce2d
    wall/lj93 wall/lj126 wall/lj1043 wall/harmonic wall/morse
    wall/colloid wall/table wall/region external print ave/time
    ave/atom ave/chunk ave/histo ave/histo/weight ave/correlate vector
    store/state property/atom halt balance'''.split())

#: Why other fixes are refused, by style prefix: the first that matches.
_FIX_REASONS = (
    (('nvt', 'npt', 'nph', 'press/', 'deform', 'box/relax'),
     'changes velocities or the box by a thermostat or barostat, which '
     'depends on more than positions, so the motion could not be run back; '
     'exact runs keep the box, and their thermostat is reversible nvt '
     '(ReversibleLammpsNose) in place of fix nvt'),
    (('nve', 'rigid', 'shake', 'rattle', 'move', 'nvk', 'nvl'),
     'integrates or constrains the atoms itself: they would be moved twice '
     '(reversible nve is the integrator, and constraints are not exact here)'),
    (('langevin', 'temp/', 'viscous', 'momentum', 'gld', 'gle', 'heat',
      'ehex', 'dpd', 'ttm', 'bd/', 'brownian'),
     'changes velocities by friction, noise or rescaling, which depends on '
     'more than positions: the motion could not be run back'),
    (('deposit', 'pour', 'evaporate', 'gcmc', 'atom/swap', 'bond/',
      'widom'),
     'adds, removes or changes atoms or bonds during a run'),
    (('wall/reflect', 'recenter', 'dt/reset'),
     'sets positions, velocities or the time step itself during a run'),
)

#: Pair styles whose forces depend on velocities or on history, by prefix.
_HISTORY_PAIRS = ('dpd', 'gran', 'lubricate', 'brownian', 'sdpd', 'mdpd',
                  'edpd', 'tdpd')

#: Long-range solvers whose force noise was measured (PPPM: rhodopsin,
#: 32,000 atoms, forces at identical positions differed by at most
#: 2.1e-13 kcal/mol/Å with max|F| 133 on 1 and 2 ranks, 73 times below
#: the guard's bound; benchmarks/lammps_pppm_noise.py).
MEASURED_KSPACE = ('pppm',)


def check_units(units):
    """ValueError unless LAMMPS's ``units`` style is one of
    ``SUPPORTED_UNITS``."""
    if units not in SUPPORTED_UNITS:
        raise ValueError(
            f'units {units} are not supported: the force-noise bound '
            f'assumes the scales of {", ".join(SUPPORTED_UNITS)}')


def check_styles(info, ours):
    """Refuse, before any step, every fix, pair style and long-range
    solver that would make the motion depend on more than positions,
    integrate the atoms a second time, or change the box.  ``info``:
    LAMMPS's ``info fixes system`` text (:func:`lammps_info`); ``ours``:
    the IDs of the exact integrator's own fixes."""
    for fix, style in re.findall(
            r'Fix\[\s*\d+\]:\s*(\S+),\s+style = (\S+),', info):
        if fix in ours or style in PASSIVE_FIXES or style.isupper():
            continue
        reason = next((why for prefixes, why in _FIX_REASONS
                       if style.startswith(prefixes)),
                      'is not known to leave the motion to the exact '
                      'integrator (only fixes that add to or set '
                      'forces, or that observe, are taken)')
        raise ValueError(
            f'fix {fix} ({style}) {reason}. Remove it (unfix {fix}) '
            'before the exact runs; for a thermostatted or constrained '
            'run, use LAMMPS\'s own integrators after reversible off')
    pair = re.search(r'Atoms\s*=.*style = (\S+)', info)
    if pair and pair.group(1).startswith(_HISTORY_PAIRS):
        raise ValueError(
            f'pair_style {pair.group(1)} computes forces from velocities '
            'or history, not from positions alone: its motion could not '
            'be run back. Exact runs need a conservative potential')
    kspace = re.search(r'Kspace style = (\S+)', info)
    if kspace and kspace.group(1) not in MEASURED_KSPACE + ('none',):
        raise ValueError(
            f'kspace_style {kspace.group(1)}: its force noise at '
            'identical positions was not measured, so the guard\'s bound '
            'may not cover it (measured: '
            f'{", ".join(MEASURED_KSPACE)}). Use kspace_style pppm')


def lammps_info(lmp, world, rank, what):
    """LAMMPS's ``info`` about ``what``, as text, on every rank
    (``world``: the ranks' :class:`~.mpi.World`).  Collective."""
    path = os.devnull
    if rank == 0:
        handle, path = tempfile.mkstemp(prefix='lammps-info-')
        os.close(handle)
    try:
        lmp.command(f'info {what} out overwrite "{path}"')
        text = Path(path).read_text() if rank == 0 else ''
    finally:
        if rank == 0:
            os.unlink(path)
    return world.share(text, rank)
