"""Cost per step of ReversibleIsotropicNPT against ASE's IsotropicMTKNPT,
and the profile of one case.

Measured by benchmarks/npt_cost.py.
"""

from __future__ import annotations

from . import Spec, block, markdown_table


LABELS = (('reversible_npt', 'ReversibleIsotropicNPT'),
          ('ase_npt', 'ASE IsotropicMTKNPT'))


def us(seconds):
    return f'{seconds * 1e6:,.0f}'


def cost_table(results):
    rows = []
    for c in results['costs']:
        row = [c['label'].split(',')[0], c['calculator'], f"{c['n_atoms']:,}",
               f"{c['steps_per_block']} × {c['rounds']}"]
        rows.append(row + [f"{us(c['median_seconds'][key])} "
                           f"({us(c['median_cpu_seconds'][key])})"
                           for key, _ in LABELS]
                    + [f"{c['ratio']:.3f} ({c['ratio_cpu']:.3f})"])
    return markdown_table(
        ['system', 'calculator', 'atoms', 'steps per block × rounds']
        + [f'{label} µs/step, wall (CPU)' for _, label in LABELS]
        + ['ratio, wall (CPU)'], rows)


def profile_tables(results):
    p = results['profile']
    parts = []
    for key, label in LABELS:
        run = p['runs'][key]
        rows = [[f"`{r['function']}`", f"{r['calls']:,}",
                 f"{r['tottime'] * 1e6 / run['steps']:,.0f}",
                 f"{r['cumtime'] * 1e6 / run['steps']:,.0f}",
                 f"{100 * r['share']:.1f}%"] for r in run['by_own_time']]
        parts.append(
            f"{label}, {p['label'].split(',')[0]} {p['n_atoms']} atoms, "
            f"{run['steps']} steps under cProfile "
            f"({run['per_step_seconds'] * 1e6:,.0f} µs/step with the "
            "profiler), by own time:\n\n"
            + markdown_table(['function', 'calls', 'own µs/step',
                              'cumulative µs/step', 'share of the run'],
                             rows))
    return '\n\n'.join(parts)


SPEC = Spec(
    'Constant pressure: cost per step against ASE IsotropicMTKNPT',
    blocks={'cost': block(cost_table), 'profile': block(profile_tables)})
