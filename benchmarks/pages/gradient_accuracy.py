"""Gradient accuracy (benchmarks/gradient_accuracy.py)."""

from __future__ import annotations

import math

from . import Spec, block, markdown_table


def finite_difference_steps(results):
    """The h of the whole-run finite differences, as stored."""
    return [float(h) for h in results['runs'][0]['rows'][0]['directions'][0]
            ['errors']]


def _short(x):
    """1e-5 rather than 1e-05."""
    return f'{x:g}'.replace('e-0', 'e-')


def _exponent(power_of_two):
    return math.frexp(power_of_two)[1] - 1


def hvp_table(results):
    hvp = results['hvp']
    steps = list(hvp[0]['errors'])
    return markdown_table(
        ['case', 'reference'] + [f'{float(s):g} Å' for s in steps],
        [[r['case'], r['reference']]
         + [f"{r['errors'][s]:.1e}" for s in steps] for r in hvp])


def run_tables(results):
    """Per case: each run length's errors against finite differences."""
    fd_h = finite_difference_steps(results)
    lines = []
    for case in results['runs']:
        lines += [f"**{case['case']}** ({case['n_atoms']} atoms)", '']
        rows = []
        for r in case['rows']:
            per_h = {h: max(d['errors'][repr(h)] for d in r['directions'])
                     for h in fd_h}
            best = max(min(d['errors'].values()) for d in r['directions'])
            rows.append([r['steps'], f"{r['growth']:.3g}", f'{best:.1e}']
                        + [f'{per_h[h]:.1e}' for h in fd_h]
                        + ['yes' if r['exact_return'] else 'NO',
                           f"{r['backward_s'] / r['forward_s']:.2f}"])
        lines += [markdown_table(
            ['steps', 'growth', 'error, best h']
            + [f'error, h={h:g}' for h in fd_h]
            + ['back at start bit for bit', 'backward / forward time'],
            rows), '']
    return '\n'.join(lines)


def values(results):
    """The finite-difference steps, and the worst case at its best h."""
    fd_h = finite_difference_steps(results)
    q = results['settings']
    case, row = max(
        ((case, r) for case in results['runs'] for r in case['rows']),
        key=lambda cr: max(min(d['errors'].values())
                           for d in cr[1]['directions']))
    per_h = [max(d['errors'][repr(h)] for d in row['directions'])
             for h in fd_h]
    return {'default_step': results['hvp'][0]['default_step'],
            'stencil_step': _short(q['stencil_step']),
            'fd_h': ', '.join(f'{h:g}' for h in fd_h),
            'position_exponent': _exponent(q['position_quantum']),
            'momentum_exponent': _exponent(q['momentum_quantum']),
            'worst': max(min(d['errors'].values())
                         for d in row['directions']),
            'worst_case': case['case'], 'worst_steps': row['steps'],
            'worst_growth': row['growth'],
            'falls': ', '.join(f'{a / b:.0f}×'
                               for a, b in zip(per_h, per_h[1:]))}


SPEC = Spec('Gradient accuracy',
            blocks={'hvp': block(hvp_table), 'runs': block(run_tables)},
            values=values)
