"""Cost per step of ReversibleIsotropicNPT against ASE's IsotropicMTKNPT,
and the profile of one case.

Measured by benchmarks/npt_cost.py, whose docstring gives the method.
"""

from __future__ import annotations

from . import markdown_table

TITLE = 'Constant pressure: cost per step against ASE IsotropicMTKNPT'

LABELS = (('reversible_npt', 'ReversibleIsotropicNPT'),
          ('ase_npt', 'ASE IsotropicMTKNPT'))


def plot(results, figures):
    """No plot: tables."""


def us(seconds):
    return f'{seconds * 1e6:,.0f}'


def cost_table(results):
    goal = results['settings']['ratio_goal']
    rows = []
    for c in results['costs']:
        row = [c['label'].split(',')[0], c['calculator'], f"{c['n_atoms']:,}",
               f"{c['steps_per_block']} × {c['rounds']}"]
        for key, _ in LABELS:
            if key in c['median_seconds']:
                row.append(f"{us(c['median_seconds'][key])} "
                           f"({us(c['median_cpu_seconds'][key])})")
            else:
                row.append('not measured')
        if 'ratio' in c:
            row += [f"{c['ratio']:.3f} ({c['ratio_cpu']:.3f})",
                    'met' if c['ratio'] <= goal else '**not met**']
        else:
            row += ['—', '—']
        rows.append(row)
    return markdown_table(
        ['system', 'calculator', 'atoms', 'steps per block × rounds']
        + [f'{label} µs/step, wall (CPU)' for _, label in LABELS]
        + ['ratio, wall (CPU)', f'≤ {goal:g}'], rows)


def profile_tables(results):
    p = results['profile']
    parts = []
    for key, label in LABELS:
        run = p['runs'].get(key)
        if run is None:
            continue
        for order, title in (('by_own_time', 'own time'),
                             ('by_cumulative_time', 'cumulative time')):
            rows = [[f"`{r['function']}`", f"{r['calls']:,}",
                     f"{r['tottime'] * 1e6 / run['steps']:,.0f}",
                     f"{r['cumtime'] * 1e6 / run['steps']:,.0f}",
                     f"{100 * r['share']:.1f}%"] for r in run[order]]
            parts.append(
                f"{label}, {p['label'].split(',')[0]} {p['n_atoms']} atoms, "
                f"{run['steps']} steps under cProfile "
                f"({run['per_step_seconds'] * 1e6:,.0f} µs/step with the "
                f"profiler), by {title}:\n\n"
                + markdown_table(['function', 'calls', 'own µs/step',
                                  'cumulative µs/step', 'share of the run'],
                                 rows))
    return '\n\n'.join(parts)


def markdown(results):
    st = results['settings']
    load = results['load_average']
    missing = results.get('reversible_missing')
    return f"""\
{f'ReversibleIsotropicNPT was not measured: {missing}.' if missing else ''}

Both integrators on copies of the same atoms, each with its own calculator,
tdamp = 100 dt, pdamp = 1000 dt: blocks of the same number of steps
alternate between them ({st['rounds']} rounds, the order rotated each
round, blocks sized to ~{st['block_seconds']:g} s of ASE's integrator);
medians of the per-step wall time, and of the process's CPU time. The load
average was {load['start'][0]:.2f} at the start, {load['before_profile'][0]:.2f}
before the profile and {load['end'][0]:.2f} at the end (1-minute values):
the machine is shared, so ratios are of interleaved medians.

{cost_table(results)}

Where the time goes (cProfile; the profiler's own overhead inflates the
functions called most often):

{profile_tables(results)}
"""
