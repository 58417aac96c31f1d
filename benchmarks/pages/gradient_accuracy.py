"""Gradient accuracy: finite-difference Hessian-vector products, and
backpropagate against finite differences of whole runs.

Measured by benchmarks/gradient_accuracy.py, whose docstring gives the
method.
"""

from __future__ import annotations

import math

from . import markdown_table, pyplot

TITLE = 'Gradient accuracy'
PLOT = 'gradient_accuracy.png'


def finite_difference_steps(results):
    """The h of the whole-run finite differences, as stored."""
    return [float(h) for h in results['runs'][0]['rows'][0]['directions'][0]
            ['errors']]


def _short(x):
    """1e-5 rather than 1e-05."""
    return f'{x:g}'.replace('e-0', 'e-')


def _exponent(power_of_two):
    return math.frexp(power_of_two)[1] - 1


def plot(results, figures):
    plt = pyplot()
    fig, (left, right) = plt.subplots(1, 2, figsize=(11, 4.2))
    for row in results['hvp']:
        steps = [float(k) for k in row['errors']]
        left.loglog(steps, list(row['errors'].values()), 'o-',
                    label=row['case'])
    default = results['hvp'][0]['default_step']
    left.axvline(default, color='grey', ls=':', label='default step')
    left.set_xlabel('finite-difference step (Å)')
    left.set_ylabel('relative error of H v')
    left.set_title('Finite-difference Hessian-vector products')
    left.legend(fontsize=7)
    for case in results['runs']:
        steps = [r['steps'] for r in case['rows']]
        best = [max(min(d['errors'].values()) for d in r['directions'])
                for r in case['rows']]
        growth = [r['growth'] for r in case['rows']]
        line, = right.loglog(steps, best, 'o-', label=f"{case['case']}: error")
        right.loglog(steps, growth, 's--', color=line.get_color(),
                     label='gradient growth')
    right.set_xlabel(f"steps ({results['settings']['timestep_fs']:g} fs)")
    right.set_title('backpropagate against whole-run finite differences')
    right.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(figures / PLOT, dpi=120)
    plt.close(fig)


def markdown(results):
    hvp = results['hvp']
    fd_h = finite_difference_steps(results)
    q = results['settings']
    steps = list(hvp[0]['errors'])
    lines = [
        'How accurate the gradients of `ReversibleVerlet.backpropagate` '
        'are (`benchmarks/gradient_accuracy.py`).',
        '',
        f'![gradient accuracy](benchmarks/{PLOT})',
        '',
        '### Finite-difference Hessian-vector products',
        '',
        'Largest component error over the largest component of the '
        'reference, for one random direction; the default step is '
        f"{hvp[0]['default_step']:g} Å. Reference: `analytic` is the "
        "calculator's exact product, `stencil` a fourth-order difference at "
        f"{_short(q['stencil_step'])} Å.",
        '',
        markdown_table(
            ['case', 'reference'] + [f'{float(s):g} Å' for s in steps],
            [[r['case'], r['reference']]
             + [f"{r['errors'][s]:.1e}" for s in steps] for r in hvp]),
        '',
        '### Whole-run gradients',
        '',
        'Linear loss `L = <a, x_T> + <b, p_T>` with random `a`, `b`; '
        'relative error of the directional derivative `<dL/dx0, u>` (and '
        'the same for `p0`) against central finite differences of the whole '
        'run with h = ' + ', '.join(f'{h:g}' for h in fd_h) + ' (Å, or amu '
        'Å / ASE time), for random `u`. "best h" is the smallest of the '
        'three errors, the largest over directions; "growth" the gradient '
        'growth over the run. Fine quanta '
        f"(2^{_exponent(q['position_quantum'])} Å, "
        f"2^{_exponent(q['momentum_quantum'])}), time step "
        f"{q['timestep_fs']:g} fs.",
        '',
    ]
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
    worst_case, worst_row = max(
        ((case, r) for case in results['runs'] for r in case['rows']),
        key=lambda cr: max(min(d['errors'].values())
                           for d in cr[1]['directions']))
    worst = max(min(d['errors'].values()) for d in worst_row['directions'])
    per_h = [max(d['errors'][repr(h)] for d in worst_row['directions'])
             for h in fd_h]
    falls = ', '.join(f'{a / b:.0f}×' for a, b in zip(per_h, per_h[1:]))
    lines += [f"Largest error at the best h: {worst:.1e} ({worst_case['case']}, "
              f"{worst_row['steps']} steps, growth {worst_row['growth']:.3g}). "
              f'There, each 10× smaller h divides the error by {falls}: '
              'the finite differences\' truncation error (∝ h², growing '
              'with the curvature of the run map) still dominates the '
              'comparison, so it bounds the error of the adjoint from '
              'above only.']
    return '\n'.join(lines)

