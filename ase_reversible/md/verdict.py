"""``check_calculator``: the integrators' verdict on a calculator before a
run.  The integrators' own checks and choices run here (:mod:`.admission`);
the probe of the forces and the cost of the chosen handling are
:mod:`ase_reversible.purity.check`'s."""

from __future__ import annotations

import numpy as np

from ..core.compositions import composition_for
from ..core.quanta import choose_momentum_quantum
from ..errors import ReversibilityError
from ..purity.check import probed_check, refused_check
from .admission import admit, checked_grid, encoded
from .hamiltonian import largest_kick
from .restart import fitting_record, grid_values
from .rigid.layout import refuse_guarded_rigid, rigid_layout
from .verlet import KICK, SCHEMES


def check_calculator(atoms, timestep=None, force_noise=None):
    """Tell whether the atoms' calculator gives exactly reversible forces.

    Runs what ``ReversibleVerlet(atoms, timestep)`` runs before its first
    step -- the checks of the atoms (calculator, masses, constraints), the
    choice of the force-purity mode under ``force_purity='auto'`` and,
    with ``timestep``, the choice of the quanta -- so that what it refuses
    is reported here, with its message.  Then it probes the forces under
    the chosen handling with :func:`~ase_reversible.probe_purity`: 7 force
    calls, and 7 more for each probe the choice itself made (an unknown
    calculator is probed, probed again from a cold start if its history
    noise is large, and again with its threads held to one if noise is
    left at the level of rounding).  Nothing about the atoms is changed;
    an ASE LennardJones or EMT gets its sorted neighbour list, as it would
    from the integrator.

    Parameters
    ----------
    atoms : ase.Atoms
        With the calculator attached and the positions a run starts from.
    timestep : float, optional
        ASE time units.  With it, the quanta are chosen as the integrator
        (scheme ``'velocity'``, order 2) would, a momentum quantum that
        would visibly change the momenta is refused as there, and the
        cost of ``'guarded'`` includes the bits of momentum precision its
        coarser quantum gives up.
    force_noise : float, optional
        eV/Å, as for the integrator (implies ``'guarded'``).

    Returns
    -------
    ~ase_reversible.purity.check.CalculatorCheck
        A refusal has ``mode`` None, the integrator's error class in
        ``refused_by`` and its message in ``advice``.
    """
    calc = atoms.calc
    if calc is None:
        raise RuntimeError('The atoms have no calculator: attach one '
                           '(atoms.calc = ...) to check it.')
    quanta = None
    try:
        masses_n, project, provider = admit(atoms, 'auto', force_noise,
                                            rigid=True)
        if rigid_layout(atoms, masses_n) is not None:
            # ReversibleVerlet's rigid bodies: their quanta are chosen for
            # the bodies, and every force provider but 'guarded' serves.
            refuse_guarded_rigid(provider, calc)
        elif timestep is not None:
            grid, fine = _grids(atoms, masses_n, project, provider, timestep)
            encoded(atoms, grid.position_quantum, grid.momentum_quantum,
                    project)
            quanta = grid.momentum_quantum, fine
    except (ReversibilityError, ValueError, RuntimeError) as error:
        # What the integrator would raise: the verdict is its refusal.
        return refused_check(calc, error)
    return probed_check(atoms, provider, quanta)


def _grids(atoms, masses_n, project, provider, timestep):
    """The grid ``ReversibleVerlet(atoms, timestep)`` would choose (refused
    as there), and the momentum quantum a pure calculator would get."""
    max_kick = largest_kick(SCHEMES['velocity'], composition_for(2),
                            float(timestep), KICK)
    # The record is read quietly: a record that does not fit is the
    # constructor's to warn about.
    record, mismatch = fitting_record(atoms.info, grid_values(atoms))
    grid = checked_grid(atoms, masses_n, project, provider, max_kick,
                        record=record if mismatch is None else None)
    fine = choose_momentum_quantum(
        masses_n, atoms.arrays.get('momenta', np.zeros((len(atoms), 3))))
    return grid, fine
