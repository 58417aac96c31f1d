"""Cost per step of ReversibleIsotropicNPT against ASE's IsotropicMTKNPT.

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


SPEC = Spec(
    'Constant pressure: cost per step against ASE IsotropicMTKNPT',
    blocks={'cost': block(cost_table)})
