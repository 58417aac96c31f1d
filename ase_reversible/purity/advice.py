"""The messages of refusals: what was seen, and what to do."""

from __future__ import annotations

import os
import sys
import warnings

from .settings import DEFAULT_FORCE_NOISE, SUMMATION_NOISE_LIMIT, _bound_for


def _impurity_advice(calc, noise, f_max, cold_start_tried=False,
                     one_thread_tried=False):
    """The ImpureForcesError message, with the remedy for the likely cause;
    ``one_thread_tried``: the probe ran with OpenMP and BLAS held to one
    thread."""
    name = type(calc).__name__
    head = (f'{name} returned forces that differ by {noise:.3g} eV/Å at '
            'identical positions after the atoms had been moved elsewhere: '
            'its forces depend on its history, which breaks exact '
            'reversal.')
    if noise <= SUMMATION_NOISE_LIMIT * max(1.0, f_max):
        # Sixteen times what was seen keeps it far below the half of the
        # bound at which guarded rounding warns that it is near.
        bound = max(DEFAULT_FORCE_NOISE, _bound_for(noise))
        return (f'{head} Noise this small comes from the order of '
                'floating-point sums (a neighbour list built elsewhere'
                + (', not threads: it stayed with OpenMP and BLAS held to '
                   'one thread' if one_thread_tried else '') + '): '
                "construct the integrator with force_purity='guarded', "
                f'force_noise={bound:.2g} (eV/Å, at least sixteen times what '
                "was seen). force_purity='trust' skips this check.")
    return (f'{head} Noise this large does not come from summation order '
            'but from state the calculator carries between calls, such as '
            'a self-consistent field (DFT, tight binding) that starts from '
            'the previous solution. '
            + ("Calling the calculator's reset() before every call "
               "(force_purity='cold-start') did not remove it. "
               if cold_start_tried else '')
            + 'Make every calculation start from '
            'scratch (reset the initial guess or wavefunction before each '
            'call, for example in a subclass whose calculate() does that '
            'first), then construct the integrator again. Guarded rounding '
            'cannot absorb noise this large: the momentum quantum would '
            'have to be so coarse that the momenta lose their precision.')


def _spot_check_advice(calc, mode, noise, calls, bound=None, wanted=None):
    """The message for forces found depending on history during a run: by
    a spot check ``calls`` force calls apart, or (``calls`` None) by a
    clean recomputation; ``bound``: the guard's, if one was broken, and
    ``wanted`` the force_noise to use instead."""
    head = (f'{type(calc).__name__} gave forces {noise:.3g} eV/Å different '
            + (f'from those it gave at the same positions {calls} force '
               'calls earlier in this run' if calls is not None else
               'from those of a neighbour list built at exactly these '
               'positions'))
    tail = (' The run so far may not reverse exactly past the point where '
            'this started; the step was not taken.')
    if bound is not None:
        return (f"{head}, more than the {bound:.3g} eV/Å that "
                f"force_purity='{mode}' relies on.{tail} Construct the "
                'integrator with force_noise='
                f'{wanted:.2g} (eV/Å, sixteen times what was '
                'seen) and run again.')
    return (f"{head}: under force_purity='{mode}' they must be equal bit "
            'for bit, so the forces are not a function of the positions '
            'alone, although the probe at construction saw no '
            f'difference.{tail} The usual cause is parallel sums whose '
            'order changes from call to call (threads, a GPU): run with one '
            'thread (OMP_NUM_THREADS=1 before Python starts), or, if the '
            "difference is at the level of rounding, use force_purity="
            f"'guarded' with force_noise={_bound_for(noise):.2g}.")


def _parallel_noise_advice(calc, noise, left, one_thread_tried=False):
    """The message for forces that a cold start makes nearly, not fully,
    pure: what is left varies from call to call at the same state.
    ``one_thread_tried``: it was left with OpenMP and BLAS held to one
    thread."""
    head = (f'{type(calc).__name__} returned forces that differ by '
            f'{noise:.3g} eV/Å at identical positions after the atoms had '
            'been moved elsewhere (a self-consistent field started from its '
            "last solution). Starting every call cold (force_purity="
            f"'cold-start') leaves {left:.3g} eV/Å: a difference at the "
            'level of rounding that varies from call to call even at the '
            'same state, as parallel sums do whose order depends on the '
            'threads. ')
    if not one_thread_tried:
        return (head + 'Run with one thread (set OMP_NUM_THREADS=1 '
                'before Python starts) and construct the integrator again.')
    return (head + 'Holding the OpenMP and BLAS thread pools to one thread '
            'during force calls (threadpoolctl) did not remove it, so the '
            'parallelism is of another kind (a GPU, threads of the '
            "calculator's own): run it serially (its documentation says "
            'how), then construct the integrator again.')


#: Files whose frames a warning is not attributed to: this package's and
#: ASE's (its run loops may call ours), so that it names the user's line.
_LIBRARY_PREFIXES = (
    os.path.dirname(os.path.dirname(os.path.abspath(__file__))) + os.sep,)


def warn_at_user_line(message, category):
    """``warnings.warn``, attributed to the first caller outside this
    package and ASE: the line of the user's script that ran the step."""
    import ase
    prefixes = _LIBRARY_PREFIXES + (os.path.dirname(ase.__file__) + os.sep,)
    if sys.version_info >= (3, 12):
        warnings.warn(message, category, skip_file_prefixes=prefixes)
        return
    frame, level = sys._getframe(0), 1
    while frame is not None and frame.f_code.co_filename.startswith(prefixes):
        frame, level = frame.f_back, level + 1
    warnings.warn(message, category, stacklevel=level)
