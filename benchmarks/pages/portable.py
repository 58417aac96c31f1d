"""The cost of the portable arithmetic of the package's calculators.

Measured by benchmarks/portable.py.
"""

from __future__ import annotations

from . import markdown_table

TITLE = 'Portable arithmetic'


def plot(results, figures):
    """No plot: tables."""


def _rows(rows, scale):
    return [([r['calculator']] if 'calculator' in r else []) + [
        r['n_atoms'], f"{r['old_seconds'] * scale:.3g}",
        f"{r['new_seconds'] * scale:.3g}",
        f"{r['new_seconds'] / r['old_seconds']:.2f}"] for r in rows]


def markdown(results):
    header = ['calculator', 'atoms', 'before ({})', 'now ({})', 'ratio']
    ms = [h.format('ms') for h in header]
    us = [h.format('µs') for h in header[1:]]
    rounds = results['settings']['rounds']
    return (
        "The package's calculators and the integrators' own float work "
        'compute with `+ - * /`, `sqrt` and fixed-order sums only, so a run '
        'gives the same bits on every CPU '
        '([force purity](force-purity.md#the-same-bits-on-every-cpu)). '
        'Their kernels before that change (numpy powers, `einsum` row sums, '
        'a BLAS dot) are kept in `benchmarks/portable.py` and timed against '
        "today's in one process, in interleaved blocks, the order rotating, "
        f'median of {rounds} rounds per call'
        + (' (one-minute load average {:.1f} at the start, {:.1f} at the end, '
           'on a machine shared with other work: ratios, not absolute '
           'times, are the result)'.format(*results['load_average'])
           if 'load_average' in results else '') + '.\n\n'
        '**Force call** (`get_forces`, positions alternating so that no '
        'cache answers):\n\n'
        + markdown_table(ms, _rows(results['forces'], 1e3))
        + '\n\n**ReversibleVerlet step** (one force call, drift, kick; '
        'the integrator is today\'s in both columns):\n\n'
        + markdown_table(ms, _rows(results['steps'], 1e3))
        + '\n\n**`sum p**2 / m`** (read by the energy check and Nosé\'s '
        'thermostat kick): a BLAS dot before, `np.sum` of the squares '
        'now:\n\n'
        + markdown_table(us, _rows(results['momentum_square'], 1e6)))
