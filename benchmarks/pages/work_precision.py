"""Work against precision: run time to reach a given energy error.

Measured by benchmarks/work_precision.py, whose docstring gives the method.
"""

from __future__ import annotations

import math

from . import Spec, block, markdown_table, pyplot



def plot_name(system):
    return f"work_precision_{system['key']}.png"


def plot(results, figures):
    for system in results['systems']:
        _plot_system(system, results['target'], figures)


STYLE = {2: 'C0', 4: 'C1', 6: 'C2', 8: 'C3', 10: 'C4'}


def _style(sweep):
    if sweep['scheme'] is None:
        # On top: velocity 2 has the same errors and would hide it.
        return dict(color='black', linestyle='-', marker='o', zorder=3,
                    linewidth=1, markersize=3)
    return dict(color=STYLE[sweep['order']], zorder=2,
                linestyle='-' if sweep['scheme'] == 'velocity' else '--',
                marker='s' if sweep['scheme'] == 'velocity' else '^',
                markerfacecolor='none' if sweep['scheme'] == 'position'
                else None)


def _plot_system(result, target, figures):
    plt = pyplot()
    fig, (ax_work, ax_dt) = plt.subplots(1, 2, figsize=(12, 5))
    for s in result['sweeps']:
        pts = [p for p in s['points'] if p['max_error'] is not None]
        if not pts:
            continue
        style = _style(s)
        ax_work.plot([p['wall_s'] for p in pts], [p['max_error'] for p in pts],
                     label=s['method'], **{'markersize': 4, **style})
        ax_dt.plot([p['dt_fs'] for p in pts], [p['max_error'] for p in pts],
                   label=s['method'], **{'markersize': 4, **style})
    for ax in (ax_work, ax_dt):
        ax.set_xscale('log')
        ax.set_yscale('log')
        ax.axhline(target, color='grey', linewidth=0.8, linestyle=':')
        ax.grid(True, which='major', alpha=0.3)
    ax_work.set_xlabel('wall time of the run without sampling (s)')
    ax_dt.set_xlabel('time step (fs)')
    for ax in (ax_work, ax_dt):
        ax.set_ylabel('max relative total-energy error')
    ax_work.set_title(f"{result['label']}: {result['formula']}, "
                      f"{result['simulated_fs']:g} fs")
    ax_dt.set_title('error against time step')
    ax_dt.legend(fontsize=7, ncol=2)
    fig.subplots_adjust(left=0.07, right=0.98, bottom=0.11, top=0.93,
                        wspace=0.22)
    fig.savefig(figures / plot_name(result), dpi=110)
    plt.close(fig)


# -- Markdown ----------------------------------------------------------------

def _g(x, digits=3):
    return '–' if x is None else f'{x:.{digits}g}'


def _e(x):
    return '–' if x is None else f'{x:.2e}'


def _time_cell(row, key):
    if row[key] is None:
        return 'not reached'
    prefix = '≤ ' if row['how'] == 'at most' else ''
    return f'{prefix}{row[key]:.3g} s'


def _converged_to(run, target, slack=0.5):
    """The smallest error reached while every halving so far showed at
    least the nominal order minus ``slack``; None if the first halving
    already fell short."""
    points, reached = run['points'], None
    for a, b, observed in zip(points, points[1:], run['observed_orders']):
        if observed < run['order'] - slack:
            break
        reached = b['max_error']
    return reached


def convergence(c):
    """Per system: what ran, and each method's halvings."""
    target = c['target']
    lines = [
]
    for r in c['systems']:
        closest = min(p['closest_to_cutoff'] for run in r['runs']
                      for p in run['points'])
        lines += [
            f"**{r['label'][0].upper() + r['label'][1:]}**: {r['formula']} "
            f"({r['atoms']} atoms{', periodic' if r['pbc'] else ''}), "
            f"asap3 LennardJones with cutoff {r['cutoff']:g} Å, "
            f"{r['temperature_K']:g} K, {r['simulated_fs']:g} fs sampled "
            f"every {r['interval_fs']:g} fs; no sampled pair came closer "
            f'than {closest:.2f} Å to the cutoff.', '']
        table = []
        for run in r['runs']:
            first, last = run['points'][0], run['points'][-1]
            reached = _converged_to(run, target)
            both = run.get('fine_both')
            table.append([
                f"{run['scheme']} {run['order']}",
                f"2^{math.log2(first['momentum_quantum']):.0f}"
                + (f" / 2^{math.log2(first['position_quantum']):.0f}"
                   if 'position_quantum' in first else ''),
                ', '.join(f"{p['dt_fs']:g}" for p in run['points']),
                ', '.join(_e(p['max_error']) for p in run['points']),
                ', '.join(f'{o:.1f}' for o in run['observed_orders']),
                _e(reached), _e(run['fine']['max_error']),
                _e(both['max_error'] if both else None), run['stop']])
        lines += [markdown_table(
            ['method', 'quanta at the first step: momentum / position',
             'dt (fs)', 'max error', 'observed order', 'nominal down to',
             'finest step, fine p', 'finest step, fine p and x', 'stop'],
            table), '']
    return '\n'.join(lines)


def summary(r):
    """The system, and each method's time to the target."""
    e0_atom = r['initial_energy_eV'] / r['atoms']
    lines = []
    if r['pbc']:
        desc = (f"{r['formula']} ({r['atoms']} atoms), periodic fcc, "
                f"`{r['calculator']}` (Cleri–Rosato parameters), "
                f"thermalised at {r['temperature_K']:g} K from the perfect "
                f"lattice; E(0) = {e0_atom:.4g} eV/atom.")
    else:
        desc = (f"{r['formula']} icosahedron ({r['atoms']} atoms) in "
                f"vacuum, `{r['calculator']}` (behind `ResultCache`, see "
                f"below) with cutoff "
                f"{r['cutoff']:g} Å; the widest interatomic distance in "
                f"any sample was {r['widest_distance']:.1f} Å, far inside "
                f"the cutoff, so no pair crosses it.  Thermalised at "
                f"{r['temperature_K']:g} K; E(0) = {e0_atom:.4g} eV/atom.")
    lines += [desc + f"  Simulated time {r['simulated_fs']:g} fs, energy "
              f"sampled every {r['interval_fs']:g} fs.", '']

    rows = r['summary']
    table = []
    for row in rows:
        table.append([row['method'], row['stages'],
                      _time_cell(row, 'wall_s'), _g(row['wall_s_ratio']),
                      _time_cell(row, 'cpu_s'), _g(row['cpu_s_ratio']),
                      _e(row['best_error']), row['stop']])
    lines += [markdown_table(
        ['method', 'force calls / step', 'wall to target', 'wall ratio',
         'CPU to target', 'CPU ratio', 'best error', 'stop'], table)]
    return '\n'.join(lines)


def every_run(r):
    table = []
    for s in r['sweeps']:
        for p in s['points']:
            table.append([s['method'], f"{p['dt_fs']:.4g}", p['steps'],
                          p['force_calls'], p['repeats'],
                          f"{p['wall_s']:.3g}",
                          f"{p['cpu_s']:.3g}",
                          p.get('failure') or _e(p['max_error']),
                          _e(p['rms_error'])])
    return markdown_table(
        ['method', 'dt (fs)', 'steps', 'force calls', 'runs', 'wall (s)',
         'CPU (s)',
         'max error', 'RMS error'], table)


def checks(r):
    """The sampling, cache, quantum and EMT checks, as paragraphs."""
    lines = []
    c = r.get('sampling_check')
    if c:
        lines += [
            f"**Sampling check.**  {c['method']} at dt = {c['dt_fs']:.4g} fs "
            f"with the energy sampled after every step ({c['steps']} steps, "
            f"the largest sampling share in the sweeps), median of "
            f"{c['repeats']} interleaved pairs of runs: the observer took "
            f"{c['sampling_wall_s']:.3g} s; the run time with it subtracted "
            f"was {c['subtracted_wall_s']:.3g} s wall / "
            f"{c['subtracted_cpu_s']:.3g} s CPU against "
            f"{c['unobserved_wall_s']:.3g} s / {c['unobserved_cpu_s']:.3g} s "
            f"for runs with no observer "
            f"({c['subtracted_wall_s'] / c['unobserved_wall_s'] - 1:+.1%} / "
            f"{c['subtracted_cpu_s'] / c['unobserved_cpu_s'] - 1:+.1%}).", '']
    cc = r.get('cache_check')
    if cc:
        text = (f"**Cached results.**  The bare `{r['calculator']}`: a "
                f"repeated `get_forces` at unchanged positions takes "
                f"{cc['repeated_call_us']:.3g} µs, a real computation "
                f"{cc['fresh_call_us']:.3g} µs.")
        if 'vv_bare_us_per_step' in cc:
            text += (f"  VelocityVerlet, which asks for the forces three "
                     f"times per step, takes {cc['vv_bare_us_per_step']:.3g}"
                     f" µs per step with the bare potential and "
                     f"{cc['vv_cached_us_per_step']:.3g} µs behind "
                     f"`ResultCache`, a cache of the last results keyed by "
                     f"the exact positions, used for every run of this "
                     f"section (ReversibleVerlet keeps its own cache and "
                     f"asks once per stage).")
        lines += [text, '']
    q = r.get('quantum_check')
    if q:
        lines += [
            f"**Momentum-quantum check.**  The most accurate "
            f"ReversibleVerlet run ({q['method']}, dt = {q['dt_fs']:.4g} fs)"
            f" used the default momentum quantum {q['default_quantum']:.3g} "
            f"(raised by the guarded force mode so that clean "
            f"recomputations stay rare) and reached {q['default_error']:.2e}"
            f"; with a quantum of {q['fine_quantum']:.3g} it reaches "
            f"{_e(q['fine_error'])} ({q['fine_clean_recomputations']} clean "
            f"recomputations, {q['fine_force_calls']} force calls instead "
            f"of {q['default_force_calls']}).", '']
    emt = r.get('emt_check')
    cut = r.get('emt_cutoff')
    if emt:
        gap = cut['fourth_neighbour'] - cut['list_cutoff']
        table = [[row['calculator'], f"{row['dt_fs']:.4g}",
                  _e(row['max_error']), _e(row['rms_error'])]
                 for row in emt]
        gains = []
        for name in dict.fromkeys(row['calculator'] for row in emt):
            coarse, fine = [row for row in emt if row['calculator'] == name]
            if coarse['max_error'] and fine['max_error']:
                gain = coarse['max_error'] / fine['max_error']
                gains.append(f'{name} {gain:.3g}×')
            else:
                gains.append(f'{name} –')
            ratio = coarse['dt_fs'] / fine['dt_fs']
        lines += [
            '**Why not EMT.**  VelocityVerlet on the same crystal with '
            "asap3's EMT and with RGL at two time steps.  For a smooth "
            f'potential, dividing the step by {ratio:g} divides the max '
            f'error by {ratio ** 2:g}; measured: ' + ', '.join(gains)
            + f".  asap3's EMT cuts its neighbour list at "
            f"{cut['list_cutoff']:.3f} Å, where its logistic cutoff "
            f"function is still {cut['weight_at_cutoff']:.2g} (ASE's EMT "
            "with `asap_cutoff=True`, which mirrors it, tells): the energy "
            'jumps whenever a pair crosses that distance, and the 4th '
            f"neighbours sit only {gap:.2f} Å outside it.", '',
            markdown_table(['calculator', 'dt (fs)', 'max error',
                                   'RMS error'], table), '']
    return '\n'.join(lines)


def of_system(make, key):
    return lambda stored: make(next(r for r in stored['results']['systems']
                                    if r['key'] == key))


SPEC = Spec(
    'Work against precision',
    blocks={**{f'{key}{part}': of_system(make, key)
               for key in ('argon_cluster', 'copper_crystal')
               for part, make in (('', summary), ('-checks', checks),
                                  ('-runs', every_run))},
            'convergence': block(convergence, 'convergence')},
    plots=(plot,),
    values=lambda results: {
        'ladder_start': ', '.join(map(str, results['ladder'][:7])),
        'half_convergence_target': results['convergence']['target'] / 2})
