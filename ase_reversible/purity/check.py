"""``check_calculator``: the verdict on a calculator before a run."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..errors import ImpureForcesError
from .choice import force_provider
from .introspection import _declares_pure
from .probe import probe_purity
from .settings import TARGET_CLEAN_RATE, _extent_factor, _round_up


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
    """

    calculator: str
    exact: bool
    mode: str | None
    probe_noise: float
    cost: str
    advice: str | None = None

    def __str__(self):
        if self.mode is None:
            return f'{self.calculator}: refused. {self.advice}'
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

    Chooses the force-purity mode as ``ReversibleVerlet(...,
    force_purity='auto')`` would, then probes the forces under that
    handling with :func:`probe_purity`: 7 force calls, and 7 more for
    each probe the choice itself made (an unknown calculator is probed,
    and probed again from a cold start if its history noise is large).  Nothing
    about the atoms is changed; an ASE LennardJones or EMT gets its
    sorted neighbour list, as it would from the integrator.

    Parameters
    ----------
    atoms : ase.Atoms
        With the calculator attached and the positions a run starts from.
    timestep : float, optional
        ASE time units.  With it, the cost of ``'guarded'`` includes the
        bits of momentum precision its coarser quantum gives up.
    force_noise : float, optional
        eV/Å, as for the integrator (implies ``'guarded'``).

    Returns
    -------
    CalculatorCheck
    """
    calc = atoms.calc
    if calc is None:
        raise RuntimeError('The atoms have no calculator: attach one '
                           '(atoms.calc = ...) to check it.')
    name = type(calc).__name__
    try:
        provider = force_provider(atoms, 'auto', force_noise)
    except ImpureForcesError as error:
        return CalculatorCheck(name, False, None, math.nan,
                               'not runnable as it is.', str(error))
    provider.forces(atoms)  # sorted lists in place before the probe
    noise = (0.0 if _declares_pure(calc)
             else probe_purity(atoms, forces=provider.forces))
    cost = _COSTS[provider.mode].format(rate=TARGET_CLEAN_RATE)
    exact, advice = noise == 0.0, None
    if provider.mode == 'guarded':
        f_max = float(np.abs(provider.forces(atoms)).max(initial=0.0))
        extent = float(np.abs(atoms.positions).max(initial=0.0))
        bound = provider.force_noise * max(1.0, f_max) * _extent_factor(extent)
        # Noise below the guard's bound cannot change a rounded kick.
        exact = noise < bound / 8
        if not exact:
            advice = (f'The noise is close to or above the bound of '
                      f'{bound:.3g} eV/Å: pass force_noise='
                      f'{_round_up(16 * noise):.2g} or larger.')
        if timestep is not None:
            from ..core.quanta import choose_momentum_quantum
            fine = choose_momentum_quantum(
                atoms.get_masses(),
                atoms.arrays.get('momenta', np.zeros((len(atoms), 3))))
            floor = provider.min_momentum_quantum(
                len(atoms), 0.5 * abs(float(timestep)), extent=extent)
            quantum = (fine if floor <= fine
                       else math.ldexp(1.0, math.frexp(floor)[1]))
            cost += (f' With this time step: a momentum quantum of '
                     f'{quantum:.3g} instead of {fine:.3g} '
                     f'({math.log2(quantum / fine):.0f} bits of precision '
                     'fewer).')
    return CalculatorCheck(name, exact, provider.mode, noise, cost, advice)
