"""The messages of refusals: what was seen, and what to do."""

from __future__ import annotations

import os
import sys
import warnings

from .introspection import torch_modules
from .settings import (DEFAULT_FORCE_NOISE, RUN_TO_RUN_SHARE,
                       SUMMATION_NOISE_LIMIT, _bound_for)


def _impurity_advice(calc, noise, f_max, cold_start_tried=False,
                     one_thread_tried=False, repeated=0.0):
    """The ImpureForcesError message, with the remedy for the likely cause;
    ``one_thread_tried``: the probe ran with OpenMP and BLAS held to one
    thread; ``repeated``: the noise between calls repeated at the same
    positions without moving the atoms (:func:`~.probe.repeat_noise`),
    which tells run-to-run nondeterminism from history
    (:func:`_run_to_run`)."""
    if _run_to_run(noise, repeated):
        return _run_to_run_advice(calc, noise, f_max, repeated,
                                  one_thread_tried)
    name = type(calc).__name__
    head = (f'{name} returned forces that differ by {noise:.3g} eV/Å at '
            'identical positions after the atoms had been moved elsewhere: '
            'its forces depend on its history, which breaks exact '
            'reversal.')
    if _rounding_level(noise, f_max):
        return (f'{head} Noise this small comes from the order of '
                'floating-point sums (a neighbour list built elsewhere'
                + (', not threads: it stayed with OpenMP and BLAS held to '
                   'one thread' if one_thread_tried else '') + '): '
                "construct the integrator with force_purity='guarded', "
                f'{_guarded_force_noise(noise)}. '
                "force_purity='trust' skips this check.")
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


def _run_to_run(noise, repeated):
    """Whether forces that differ by ``noise`` after the atoms were moved
    away and back, and by ``repeated`` between calls repeated at the same
    positions (both eV/Å), vary from call to call rather than with the
    calculator's history: the repeats vary nearly as much.  A history is
    carried on by a repeat too (a self-consistent field refined from its
    last solution at the same positions), but changes far less."""
    return repeated > 0 and repeated >= RUN_TO_RUN_SHARE * noise


def _rounding_level(noise, f_max):
    """Whether ``noise`` (eV/Å) is at the level of rounding for forces up
    to ``f_max``: guarded rounding can absorb it."""
    return noise <= SUMMATION_NOISE_LIMIT * max(1.0, f_max)


def _guarded_force_noise(noise):
    """The ``force_noise=...`` words for guarded rounding of ``noise``."""
    # Sixteen times what was seen keeps it far below the half of the
    # bound at which guarded rounding warns that it is near.
    bound = max(DEFAULT_FORCE_NOISE, _bound_for(noise))
    return (f'force_noise={bound:.2g} (eV/Å, at least sixteen times what '
            'was seen)')


def _run_to_run_head(calc, noise, repeated):
    """The opening of a refusal for forces that vary between calls at the
    same positions."""
    return (f'{type(calc).__name__} returned forces that differ by '
            f'{noise:.3g} eV/Å at identical positions, and by {repeated:.3g} '
            'eV/Å between calls repeated at the same positions without '
            'moving the atoms: run-to-run nondeterminism (parallel sums '
            'whose order changes from call to call, as GPU atomic adds and '
            'threads make), which breaks exact reversal. ')


def _run_to_run_advice(calc, noise, f_max, repeated, one_thread_tried):
    """The refusal for run-to-run nondeterminism in a calculator that holds
    no torch model."""
    head = _run_to_run_head(calc, noise, repeated)
    if one_thread_tried:
        head += ('Holding the OpenMP and BLAS thread pools to one thread '
                 'during force calls (threadpoolctl) did not remove it. '
                 'Run the calculator serially or in its deterministic mode '
                 '(its documentation says how)')
    else:
        head += ('Run with one thread (OMP_NUM_THREADS=1 before Python '
                 'starts), or the calculator in its deterministic mode')
    if _rounding_level(noise, f_max):
        return (f"{head}, or construct the integrator with force_purity="
                f"'guarded', {_guarded_force_noise(noise)}.")
    return (f'{head}, then construct the integrator again. Guarded rounding '
            'cannot absorb noise this large: the momentum quantum would '
            'have to be so coarse that the momenta lose their precision.')


def _torch_advice(calc, noise, f_max, repeated):
    """The refusal for a calculator holding torch modules whose forces
    vary between calls at the same positions even under PyTorch's
    deterministic kernels."""
    head = _run_to_run_head(calc, noise, repeated)
    tried = ("PyTorch's deterministic kernels (torch.use_deterministic_"
             "algorithms(True, warn_only=True)) were held around the calls "
             'and did not remove it: an operation of the model has no '
             'deterministic kernel (PyTorch warned which), or the '
             'calculator sums outside PyTorch. ')
    left = ('Run the model in float64 (a GPU\'s atomic adds then leave noise '
            'near 1e-17 eV/Å, which guarded rounding absorbs, where float32 '
            "leaves 1e-9) or on the CPU (device='cpu'), whose kernels are "
            'deterministic')
    if _rounding_level(noise, f_max):
        left += (", or construct the integrator with force_purity="
                 f"'guarded', {_guarded_force_noise(noise)}: its clean "
                 'recomputations would still vary, so a kick they decide can '
                 'come out differently on the way back, rarely')
    return f'{head}{tried}{left}; then construct the integrator again.'


def _cublas_advice(calc, noise, problem):
    """The refusal for a torch model on CUDA whose forces vary at the same
    positions, where deterministic kernels cannot run: ``problem`` is
    :func:`~ase_reversible.core.kernels.cublas_problem`'s reason."""
    return (f'{type(calc).__name__} holds a torch model on CUDA whose forces '
            f'differ by {noise:.3g} eV/Å at identical positions; PyTorch\'s '
            f'deterministic kernels would make them pure, but {problem}')


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
            'thread (OMP_NUM_THREADS=1 before Python starts)'
            + (", its torch model under PyTorch's deterministic kernels "
               '(torch.use_deterministic_algorithms(True))'
               if torch_modules(calc) else '')
            + ', or, if the difference is at the level of rounding, use '
            f"force_purity='guarded' with force_noise="
            f'{_bound_for(noise):.2g}.')


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
