"""Admission: what every reversible dynamics checks of the atoms it is
constructed on and chooses from them (masses, constraint projection, force
provider, grid), before anything is changed; :func:`.verdict.check_calculator`
runs the same, so that its verdict is the integrators'."""

from __future__ import annotations

import numpy as np
from ase import Atoms

from ..core.codec import encode
from ..core.quanta import choose_grid
from ..purity import force_provider
from .checks import (checked_masses, refuse_calculator_without_forces,
                     refuse_coarse_momentum_quantum)
from .constraints import constraint_projection
from .watch import refuse_unholdable_values


def projected_momenta(atoms, project):
    """The atoms' momenta ``[n_atoms, 3]`` projected onto the constraints."""
    p_nc = atoms.get_momenta()
    project(p_nc)
    return p_nc


def encoded(atoms, position_quantum, momentum_quantum, project):
    """The atoms' positions and projected momenta snapped to the grid, as
    int64 counts by variable name; under FixCom the momentum counts sum to
    zero (a net momentum removed in proportion to mass, as ASE does)."""
    counts = encode(projected_momenta(atoms, project), momentum_quantum,
                    'momentum')
    centre = getattr(project, 'centre', None)
    if centre is not None:
        counts = centre.balanced_counts(counts)
    return {'position': encode(atoms.positions, position_quantum, 'position'),
            'momentum': counts}


def admit(atoms, force_purity, force_noise, rigid=False):
    """What every reversible dynamics checks of the atoms it is
    constructed on, and chooses from them: ``(masses_n, project,
    purity)``, the masses ``[n_atoms]`` (amu), the constraint projection
    and the force provider (``rigid``: rigid bodies are left to the
    dynamics).  Raises as the constructors do, before anything is changed; :func:`ase_reversible.check_calculator` runs it
    too, so that its verdict is the integrators'."""
    if not isinstance(atoms, Atoms):
        raise TypeError(
            f'The reversible integrators run ase.Atoms, got '
            f'{type(atoms).__name__}: filters that move the cell '
            '(UnitCellFilter, FrechetCellFilter, ...) are not supported; '
            'pass the Atoms themselves. To let the cell move at constant '
            'pressure, use ReversibleIsotropicNPT on the Atoms (or '
            'ReversibleNPT for a cell that changes shape).')
    refuse_unholdable_values(atoms)
    refuse_calculator_without_forces(atoms.calc, 'constructing the integrator')
    masses_n = checked_masses(atoms)
    project = constraint_projection(atoms, rigid)
    purity = force_provider(atoms, force_purity, force_noise)
    return masses_n, project, purity


def checked_grid(atoms, masses_n, project, purity, max_kick,
                 position_quantum=None, momentum_quantum=None, record=None):
    """The grid a dynamics runs the atoms on (the momentum quantum no finer
    than ``purity`` needs for kicks of up to ``max_kick`` ASE time units),
    refused (:class:`~ase_reversible.CoarseQuantumError`) if its momentum
    quantum would visibly change the momenta."""
    momenta = atoms.arrays.get('momenta', np.zeros((len(atoms), 3)))
    grid, origin = choose_grid(
        atoms.positions, atoms.cell, atoms.pbc, masses_n, momenta,
        position_quantum=position_quantum,
        momentum_quantum=momentum_quantum, record=record,
        momentum_floor=purity.min_momentum_quantum(
            len(atoms), max_kick,
            extent=float(np.abs(atoms.positions).max(initial=0.0))))
    refuse_coarse_momentum_quantum(
        masses_n, projected_momenta(atoms, project), grid, origin, purity)
    return grid
