"""What full precision under asap3 would take.

Measured by benchmarks/full_precision.py.
"""

from __future__ import annotations

from . import markdown_table

TITLE = 'Full precision under asap3: the options'


def plot(results, figures):
    """No plot: one table."""


def _log2(value):
    return '-' if value is None else f'2^{value:g}'


def markdown(results):
    rows = []
    for r in results['rows']:
        rows.append([
            r['system'], r['calculator'],
            f"{r['noise_median']:.1e} / {r['noise_max']:.1e}",
            _log2(r['q_pure_log2']), _log2(r['q_guarded_log2']),
            _log2(r['q_measured_bound_log2']),
            f"{r['band_fraction_at_pure_quantum']:.2g}",
            f"{r['clean_per_step_at_pure_quantum']:.2g}",
            f"{r['clean_seconds'] / r['force_call_seconds']:.1f}"])
    rate = results['target_clean_rate']
    text = [
        'Each asap3 system ran ReversibleVerlet (5 fs, guarded) and, every '
        '10 steps, compared the forces the calculator gave with those of a '
        'neighbour list built at exactly the present positions '
        '(`benchmarks/full_precision.py`). "Quantum for 1% clean" is the '
        'momentum quantum that keeps clean recomputations at '
        f'{rate:.0%} of the kicks with the largest noise measured here as '
        'the bound instead of the default one. The last three columns '
        "assume the pure calculator's quantum with that bound: the "
        'fraction of kick components inside the guard band, the chance '
        'that a step needs a clean recomputation, and what one costs in '
        'force calls (a list rebuilt at exactly these positions; also the '
        'cost of rebuilding every step).', '',
        markdown_table(
            ['system', 'calculator',
             'noise median / max (eV/Å)', 'quantum, pure',
             'quantum, guarded (auto)', 'quantum for 1% clean, measured '
             'bound', 'band fraction at pure quantum',
             'P(clean) per step at pure quantum',
             'clean recomputation (force calls)'], rows), '']
    return '\n'.join(text)
