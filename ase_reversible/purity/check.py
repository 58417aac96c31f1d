"""The verdict on a calculator before a run, :class:`CalculatorCheck`:
its probe and cost here, the integrators' own checks before it in
:func:`ase_reversible.md.verdict.check_calculator`."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .deterministic import DeterministicKernels
from .introspection import _declares_pure
from .probe import probe_purity
from .settings import (TARGET_CLEAN_RATE, _bound_for, _near_bound,
                       guard_bound)


@dataclass(frozen=True)
class CalculatorCheck:
    """What :func:`~ase_reversible.check_calculator` found; ``str()`` gives
    a summary.

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


def refused_check(calc, error):
    """The verdict on ``calc`` that the integrators refuse with ``error``
    (the exception they raise)."""
    return CalculatorCheck(type(calc).__name__, False, None, math.nan,
                           'not runnable as it is.', str(error),
                           type(error).__name__)


def probed_check(atoms, provider, momentum_quanta=None):
    """The verdict on the atoms' calculator under ``provider`` (the force
    provider ``force_purity='auto'`` chose for it): probed with
    :func:`probe_purity` unless it declares itself pure.

    ``momentum_quanta``: ``(chosen, fine)``, the momentum quantum the
    integrator chose for a time step and the one a pure calculator would
    get (amu Å / ASE time unit), for the cost of ``'guarded'``; None if no
    time step was given.
    """
    calc = atoms.calc
    provider.forces(atoms)  # sorted lists in place before the probe
    noise = (0.0 if _declares_pure(calc)
             else probe_purity(atoms, forces=provider.forces))
    cost = _COSTS[provider.mode].format(rate=TARGET_CLEAN_RATE)
    if provider.one_thread is not None:
        cost += _ONE_THREAD_COST
    kernels = [calls for context, calls in provider.holds
               if isinstance(context, DeterministicKernels)]
    if kernels:
        cost += (_KERNELS_COST if 'forces' in kernels[0]
                 else _CLEAN_KERNELS_COST)
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
        if momentum_quanta is not None:
            quantum, fine = momentum_quanta
            cost += (f' With this time step: a momentum quantum of '
                     f'{quantum:.3g} instead of {fine:.3g} '
                     f'({math.log2(quantum / fine):.0f} bits of precision '
                     'fewer).')
    return CalculatorCheck(type(calc).__name__, exact, provider.mode, noise,
                           cost, advice)


_ONE_THREAD_COST = (' Every force call runs with OpenMP and BLAS held to '
                    'one thread (threadpoolctl), since parallel sums in '
                    'threads vary from call to call.')
_KERNELS_COST = (" Every force call runs under PyTorch's deterministic "
                 'kernels, since the GPU\'s parallel sums vary from call to '
                 'call (+6% per call measured for MACE on an NVIDIA H200).')
_CLEAN_KERNELS_COST = (" The clean recomputations run under PyTorch's "
                       'deterministic kernels, the other calls as they are.')
