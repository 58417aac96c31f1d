"""The messages of refusals: what was seen, and what to do."""

from __future__ import annotations

from .settings import DEFAULT_FORCE_NOISE, SUMMATION_NOISE_LIMIT, _round_up


def _impurity_advice(calc, noise, f_max, cold_start_tried=False):
    """The ImpureForcesError message, with the remedy for the likely cause."""
    name = type(calc).__name__
    head = (f'{name} returned forces that differ by {noise:.3g} eV/Å at '
            'identical positions after the atoms had been moved elsewhere: '
            'its forces depend on its history, which breaks exact '
            'reversal.')
    if noise <= SUMMATION_NOISE_LIMIT * max(1.0, f_max):
        # Sixteen times what was seen keeps it below the bound / 8 at
        # which guarded rounding warns that the bound is being approached.
        bound = max(DEFAULT_FORCE_NOISE, _round_up(16 * noise))
        return (f'{head} Noise this small comes from the order of '
                'floating-point sums (a neighbour list built elsewhere): '
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


def _spot_check_advice(calc, mode, noise, calls, bound=None):
    """The message for forces found depending on history during a run: by
    a spot check ``calls`` force calls apart, or (``calls`` None) by a
    clean recomputation; ``bound``: the guard's, if one was broken."""
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
                f'{_round_up(16 * noise):.2g} (eV/Å, sixteen times what was '
                'seen) and run again.')
    return (f"{head}: under force_purity='{mode}' they must be equal bit "
            'for bit, so the forces are not a function of the positions '
            'alone, although the probe at construction saw no '
            f'difference.{tail} The usual cause is parallel sums whose '
            'order changes from call to call (threads, a GPU): run with one '
            'thread (OMP_NUM_THREADS=1 before Python starts), or, if the '
            "difference is at the level of rounding, use force_purity="
            f"'guarded' with force_noise={_round_up(16 * noise):.2g}.")


def _parallel_noise_advice(calc, noise, left):
    """The message for forces that a cold start makes nearly, not fully,
    pure: what is left varies from call to call at the same state."""
    return (f'{type(calc).__name__} returned forces that differ by '
            f'{noise:.3g} eV/Å at identical positions after the atoms had '
            'been moved elsewhere (a self-consistent field started from its '
            "last solution). Starting every call cold (force_purity="
            f"'cold-start') leaves {left:.3g} eV/Å: a difference at the "
            'level of rounding that varies from call to call even at the '
            'same state, as parallel sums do whose order depends on the '
            'threads (OpenMP). Run with one thread (set OMP_NUM_THREADS=1 '
            'before Python starts) and construct the integrator again.')
