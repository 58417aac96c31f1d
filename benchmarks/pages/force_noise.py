"""Force noise of each calculator and the cost of a neighbour-list rebuild.

Measured by benchmarks/force_noise.py.
"""

from __future__ import annotations

from . import markdown_table

TITLE = 'Force noise and rebuild cost'


def plot(results, figures):
    """No plot: one table."""


def markdown(results):
    rows = [[r['calculator'], r['system'],
             ', '.join(f'{d:.1e}' for d in r['max_force_difference']),
             f"{r['force_call_seconds'] * 1e3:.2f}",
             f"{r['fresh_list_seconds'] * 1e3:.2f}",
             f"{r['fresh_list_seconds'] / r['force_call_seconds']:.1f}"]
            for r in results['rows']]
    return (
        'Forces at the same positions from a fresh calculator and from one '
        'whose neighbour list was built 0.25 Å, then 0.05 Å away, over '
        f"{results['trials']} trials (largest difference per trial); and "
        'the median over '
        f"{results['rounds']} interleaved rounds of a force call against "
        'one with a fresh calculator, which builds its list anew '
        '(`benchmarks/force_noise.py`).\n\n'
        + markdown_table(['calculator', 'system',
                          'max force difference per trial (eV/Å)',
                          'force call (ms)',
                          'with a fresh neighbour list (ms)', 'ratio'],
                         rows))
