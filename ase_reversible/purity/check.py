"""``check_calculator``: the verdict on a calculator before a run."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .introspection import _declares_pure
from .probe import probe_purity
from .settings import (TARGET_CLEAN_RATE, _bound_for, _near_bound,
                       guard_bound)


@dataclass(frozen=True)
class CalculatorCheck:
    """What :func:`check_calculator` found; ``str()`` gives a summary.

    Attributes
    ----------
    calculator : str
        The calculator's class name.
    exact : bool
        Whether a run with it reverses bit for bit under ``mode``.
    mode : str or None
        The force-purity mode ``force_purity='auto'`` chooses (``'trust'``,
        ``'sorted'``, ``'guarded'``), None if it refuses the calculator.
    probe_noise : float
        Largest force difference at identical positions that the probe
        saw after the mode's handling (eV/Å); 0.0 for a declared-pure
        calculator, which is not probed; NaN for a refused one (its
        message has the numbers).
    cost : str
        What the mode costs, in force calls and in momentum precision.
    advice : str or None
        For a refused calculator, the error's message: what to do.
    refused_by : str or None
        For a refused calculator, the class of the error the integrator
        raises (``'ImpureForcesError'``, ``'UnsupportedConstraintError'``,
        ...).
    """

    calculator: str
    exact: bool
    mode: str | None
    probe_noise: float
    cost: str
    advice: str | None = None
    refused_by: str | None = None

    def __str__(self):
        if self.mode is None:
            return (f'{self.calculator}: refused ({self.refused_by}). '
                    f'{self.advice}')
        verdict = (f"exact, force_purity='{self.mode}'" if self.exact
                   else f"not exact under force_purity='{self.mode}'")
        text = (f'{self.calculator}: {verdict}; probe noise '
                f'{self.probe_noise:.3g} eV/Å. Cost: {self.cost}')
        return text + (f' {self.advice}' if self.advice else '')


_COSTS = {
    'trust': 'none: forces are used as the calculator returns them.',
    'sorted': 'one extra force call when the sorted neighbour list is '
              'installed, nothing per step.',
    'cold-start': 'every force call starts its self-consistent field from '
                  'scratch instead of from the previous solution (more '
                  'iterations per call).',
    'guarded': 'a clean recomputation (a neighbour-list rebuild and a '
               'force call) for about {rate:.0%} of the kicks, and a '
               'momentum quantum raised so that they stay that rare.',
}


def check_calculator(atoms, timestep=None, force_noise=None):
    """Tell whether the atoms' calculator gives exactly reversible forces.

    Runs what ``ReversibleVerlet(atoms, timestep)`` runs before its first
    step -- the checks of the atoms (calculator, masses, constraints), the
    choice of the force-purity mode under ``force_purity='auto'`` and,
    with ``timestep``, the choice of the quanta -- so that what it refuses
    is reported here, with its message.  Then it probes the forces under
    the chosen handling with :func:`probe_purity`: 7 force calls, and 7
    more for each probe the choice itself made (an unknown calculator is
    probed, probed again from a cold start if its history noise is large,
    and again with its threads held to one if noise is left at the level
    of rounding).  Nothing about the atoms is changed; an ASE LennardJones
    or EMT gets its sorted neighbour list, as it would from the
    integrator.

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
    CalculatorCheck
        A refusal has ``mode`` None, the integrator's error class in
        ``refused_by`` and its message in ``advice``.
    """
    from ..errors import ReversibilityError
    from ..md.base import admit, checked_grid, encoded

    calc = atoms.calc
    if calc is None:
        raise RuntimeError('The atoms have no calculator: attach one '
                           '(atoms.calc = ...) to check it.')
    name = type(calc).__name__
    try:
        masses_n, project, provider = admit(atoms, 'auto', force_noise)
        if timestep is not None:
            grid, fine = _grids(atoms, masses_n, project, provider, timestep,
                                checked_grid)
            encoded(atoms, grid.position_quantum, grid.momentum_quantum,
                    project)
    except (ReversibilityError, ValueError, RuntimeError) as error:
        # What the integrator would raise: the verdict is its refusal.
        return CalculatorCheck(name, False, None, math.nan,
                               'not runnable as it is.', str(error),
                               type(error).__name__)
    provider.forces(atoms)  # sorted lists in place before the probe
    noise = (0.0 if _declares_pure(calc)
             else probe_purity(atoms, forces=provider.forces))
    cost = _COSTS[provider.mode].format(rate=TARGET_CLEAN_RATE)
    if provider.one_thread is not None:
        cost += _ONE_THREAD_COST
    exact, advice = noise == 0.0, None
    if provider.mode == 'guarded':
        f_max = float(np.abs(provider.forces(atoms)).max(initial=0.0))
        extent = float(np.abs(atoms.positions).max(initial=0.0))
        bound = guard_bound(provider.force_noise, extent, f_max)
        # Noise below the guard's bound cannot change a rounded kick; a
        # run meets more positions than the probe, so noise near the
        # bound (where the run warns) is not called exact.
        exact = not _near_bound(noise, bound)
        if not exact:
            advice = (f'The noise is close to or above the bound of '
                      f'{bound:.3g} eV/Å: pass '
                      f'force_noise='
                      f'{_bound_for(noise * provider.force_noise / bound):.2g}'
                      ' or larger.')
        if timestep is not None:
            quantum = grid.momentum_quantum
            cost += (f' With this time step: a momentum quantum of '
                     f'{quantum:.3g} instead of {fine:.3g} '
                     f'({math.log2(quantum / fine):.0f} bits of precision '
                     'fewer).')
    return CalculatorCheck(name, exact, provider.mode, noise, cost, advice)


_ONE_THREAD_COST = (' Every force call runs with OpenMP and BLAS held to '
                    'one thread (threadpoolctl), since parallel sums in '
                    'threads vary from call to call.')


def _grids(atoms, masses_n, project, provider, timestep, checked_grid):
    """The grid ``ReversibleVerlet(atoms, timestep)`` would choose (refused
    as there), and the one a pure calculator would get."""
    from ..core.compositions import composition_for
    from ..md.hamiltonian import largest_kick
    from ..md.verlet import KICK, SCHEMES
    max_kick = largest_kick(SCHEMES['velocity'], composition_for(2),
                            float(timestep), KICK)
    grid = checked_grid(atoms, masses_n, project, provider, max_kick,
                        record=_fitting_record(atoms))
    from ..core.quanta import choose_momentum_quantum
    fine = choose_momentum_quantum(
        masses_n, atoms.arrays.get('momenta', np.zeros((len(atoms), 3))))
    return grid, fine


def _fitting_record(atoms):
    """The restart record in ``atoms.info`` if the integrator would resume
    from it (it fits the atoms), else None; read quietly."""
    from ..core.record import read_record, record_mismatch
    record = read_record(atoms.info)
    if record is None or record_mismatch(
            record, {'position': atoms.positions,
                     'momentum': atoms.arrays.get('momenta')}) is not None:
        return None
    return record
