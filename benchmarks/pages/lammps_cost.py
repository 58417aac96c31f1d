"""ReversibleLammps against LAMMPS's fix nve, on 1 and 2 MPI ranks.

Measured by benchmarks/lammps_cost.py, whose docstring gives the method.
"""

from __future__ import annotations

import math

from . import markdown_table, pyplot

TITLE = 'Exact runs inside LAMMPS'
PLOT = 'lammps_cost.png'

#: Timer sections shown, in LAMMPS's order; the rest go to 'other'.
SHOWN_SECTIONS = ('Pair', 'Neigh', 'Comm', 'Modify')


def ratio(case):
    m = case['median']
    return m['exact']['ms_per_step'] / m['nve']['ms_per_step']


def loop_ratio(case):
    m = case['median']
    return m['exact']['loop_ms_per_step'] / m['nve']['loop_ms_per_step']


def uses(results, use):
    return [c for c in results['cases'] if use in c['uses']]


def goal_cases(results):
    return [c for c in results['cases']
            if c['natoms'] >= results['goal_min_atoms']]


def median_block(blocks):
    """The block of median wall time per step (the lower one of two)."""
    ordered = sorted(blocks, key=lambda b: b['wall_seconds'] / b['steps'])
    return ordered[(len(ordered) - 1) // 2]


def breakdown(case, name):
    """ms per step of the median block of ``name``: LAMMPS's timer sections,
    the rest of its loop, and the time outside the loop (each run's setup,
    the Python around it); they add up to the block's wall time."""
    block = median_block(case['blocks'][name])
    per_step = 1e3 / block['steps']
    parts = block['breakdown_seconds']
    shown = {s: per_step * parts.get(s, 0.0) for s in SHOWN_SECTIONS}
    shown['other'] = per_step * block['loop_seconds'] - sum(shown.values())
    shown['outside loop'] = per_step * (block['wall_seconds']
                                        - block['loop_seconds'])
    return shown


def plot(results, figures):
    plt = pyplot()
    fig, (left, right) = plt.subplots(1, 2, figsize=(11, 4.3))
    size = sorted(uses(results, 'size'), key=lambda c: c['natoms'])
    if size:
        left.plot([c['natoms'] for c in size], [ratio(c) for c in size],
                  'o-', label='Ar LJ, 1 rank')
    for c in results['cases']:
        if c in size:
            continue
        marker = 's' if c['system'] == 'copper' else '^'
        left.plot(c['natoms'], ratio(c), marker, label=c['label'])
    left.axhline(results['goal_ratio'], color='k', lw=0.8, ls=':',
                 label=f"goal ≤ {results['goal_ratio']:g} "
                       f"(N ≥ {results['goal_min_atoms']:g})")
    left.axhline(1.0, color='grey', lw=0.5)
    left.set_xscale('log')
    left.set_xlabel('number of atoms')
    left.set_ylabel('exact / fix nve, wall time per step')
    left.set_title('Time per step relative to fix nve')
    left.legend(fontsize=7)

    # Per-step time of each case, both instances, stacked by where it
    # goes, in units of fix nve's step.
    names = ['nve', 'exact']
    colours = plt.rcParams['axes.prop_cycle'].by_key()['color']
    labels, top = [], 0.0
    for i, c in enumerate(results['cases']):
        unit = c['median']['nve']['ms_per_step']
        for j, name in enumerate(names):
            x = 3 * i + j
            bottom = 0.0
            for colour, (part, value) in zip(
                    colours, breakdown(c, name).items()):
                right.bar(x, value / unit, bottom=bottom, color=colour,
                          label=part if i == 0 and j == 0 else None,
                          edgecolor='k' if name == 'exact' else None,
                          linewidth=0.5)
                bottom += value / unit
            top = max(top, bottom)
        labels.append((3 * i + 0.5, c['label'].replace(', ', '\n')
                       .replace(f" {c['natoms']}", f"\n{c['natoms']}")))
    right.set_xticks([x for x, _ in labels])
    right.set_xticklabels([t for _, t in labels], fontsize=6)
    right.set_ylabel("time per step / fix nve's")
    right.set_title('Where a step goes: fix nve (left), exact (right)')
    right.set_ylim(0, 1.3 * top)
    right.legend(fontsize=7, loc='upper left', ncol=3)
    fig.tight_layout()
    fig.savefig(figures / PLOT, dpi=110)
    plt.close(fig)


def _ms(value):
    return f'{value:.3g}' if abs(value) < 100 else f'{value:.0f}'


def _power_of_two(value):
    return f'2^{math.frexp(value)[1] - 1}'


def goal_sentence(results):
    cases = goal_cases(results)
    goal, n_min = results['goal_ratio'], results['goal_min_atoms']
    if not cases:
        return (f'The goal (exact within {goal:.2f}x of fix nve per step at '
                f'N ≥ {n_min:,}) was not measured here: no case has that '
                'many atoms.')
    worst = max(cases, key=ratio)
    best = min(cases, key=ratio)
    met = all(ratio(c) <= goal for c in cases)
    return (f"**Goal {'met' if met else 'not met'}**: exact within "
            f'{goal:.2f}x of fix nve per step at N ≥ {n_min:,}. Measured '
            'there: '
            f'from {ratio(best):.2f}x ({best["label"]}) to '
            f'{ratio(worst):.2f}x ({worst["label"]}) in wall time per step; '
            f'{min(loop_ratio(c) for c in cases):.2f}x to '
            f'{max(loop_ratio(c) for c in cases):.2f}x in LAMMPS\'s loop '
            'time, which leaves out the setup of each run.')


def pair_sentence(cases):
    excess = [c['median']['exact']['breakdown_ms_per_step']['Pair']
              / c['median']['nve']['breakdown_ms_per_step']['Pair'] - 1
              for c in cases]
    return ("The exact instance's Pair time per step is "
            f'{min(excess):.0%} to {max(excess):.0%} above that of fix nve '
            'on the same system.')


def markdown(results):
    cases = results['cases']
    rows = []
    for c in cases:
        nve, exact = c['median']['nve'], c['median']['exact']
        rows.append([
            c['label'], f"{c['natoms']:,}", c['ranks'], c['steps'],
            _ms(nve['ms_per_step']), _ms(exact['ms_per_step']),
            f'**{ratio(c):.2f}**', f'{loop_ratio(c):.2f}',
            f"{exact['clean_per_step']:.3f}"
            + (f" ({exact['sort_retries']} sort retries)"
               if exact['sort_retries'] else ''),
            ' / '.join(str(sum(b['neighbor_builds']
                               for b in c['blocks'][name]))
                       for name in ('nve', 'exact')),
            f"{max(nve['spread'], exact['spread']):.0%}"])
    lines = [
        'The same input in two LAMMPS instances of one process per rank, '
        "one integrated by `fix nve`, one by `ReversibleLammps`; blocks of "
        f"`run M` and `rev.run(M)` alternate, {cases[0]['rounds']} of each "
        'after a warm-up block, and the medians per step are compared '
        f"(`benchmarks/lammps_cost.py`; time step {results['timestep_ps']!r}"
        f" ps, LAMMPS {cases[0]['lammps_version']}). Machine: "
        f"{results['cpu']}, {results['cores']} cores, so 2 ranks keep "
        'every core busy. Wall time per step includes the setup that starts '
        "every `run` and, on the exact side, its clean recomputations; "
        "LAMMPS's loop time leaves both out. Block spread: (slowest - "
        'fastest) / median block, the worse of the two instances.',
        '',
        goal_sentence(results),
        '',
        f'![exact against fix nve](benchmarks/{PLOT})',
        '',
        markdown_table(
            ['case', 'atoms', 'ranks', 'M (steps per block)',
             'fix nve (ms/step)', 'exact (ms/step)', 'exact / nve',
             'exact / nve, loop time', 'clean recomputations per step',
             'list builds in the loops: nve / exact',
             'block spread'], rows),
        '',
        '### Where a step goes',
        '',
        "Milliseconds per step from LAMMPS's timer (average over ranks) in "
        'the block of median wall time; "outside loop" is wall time minus '
        'loop time: '
        'the setup of each run (and of each clean recomputation) and the '
        "Python around it. The exact path's kick is a Python callback "
        '(`fix external`) and its drift a `fix move` of atom-style '
        'variables, both counted under Modify.',
        '',
        markdown_table(
            ['case', 'integrator'] + list(breakdown(cases[0], 'nve'))
            + ['total'],
            [[c['label'], name]
             + [_ms(v) for v in breakdown(c, name).values()]
             + [_ms(sum(breakdown(c, name).values()))]
             for c in cases for name in ('nve', 'exact')]),
        '',
        pair_sentence(cases),
    ]
    strong = {}
    for c in uses(results, 'strong'):
        strong.setdefault((c['system'], c['natoms']), {})[c['ranks']] = c
    strong_rows = []
    for (system, natoms), by_ranks in strong.items():
        if 1 not in by_ranks or len(by_ranks) < 2:
            continue
        one = by_ranks[1]
        for ranks, c in sorted(by_ranks.items()):
            if ranks == 1:
                continue
            speedup = {n: one['median'][n]['ms_per_step']
                       / c['median'][n]['ms_per_step'] for n in ('nve', 'exact')}
            strong_rows.append([
                one['label'].split(',')[0], ranks,
                f"{speedup['nve']:.2f} ({speedup['nve'] / ranks:.0%})",
                f"{speedup['exact']:.2f} ({speedup['exact'] / ranks:.0%})",
                f'{ratio(one):.2f} → {ratio(c):.2f}'])
    if strong_rows:
        lines += [
            '', '### Strong scaling', '',
            'Speed-up from 1 rank to R ranks on the same system (parallel '
            'efficiency), and exact / nve at 1 and at R ranks.', '',
            markdown_table(['system', 'R', 'fix nve speed-up',
                            'exact speed-up', 'exact / nve, 1 → R'],
                           strong_rows)]
    weak = sorted(uses(results, 'weak'), key=lambda c: c['ranks'])
    if len(weak) >= 2 and weak[0]['ranks'] == 1:
        one = weak[0]
        weak_rows = [[c['label'], f"{c['natoms'] // c['ranks']:,}",
                      f"{one['median']['nve']['ms_per_step'] / c['median']['nve']['ms_per_step']:.0%}",
                      f"{one['median']['exact']['ms_per_step'] / c['median']['exact']['ms_per_step']:.0%}",
                      f'{ratio(c):.2f}'] for c in weak]
        lines += [
            '', '### Weak scaling', '',
            'The same number of atoms per rank; efficiency is the time per '
            'step on 1 rank over that on R ranks.', '',
            markdown_table(['case', 'atoms per rank', 'fix nve efficiency',
                            'exact efficiency', 'exact / nve'], weak_rows)]
    model_rows = []
    for c in cases:
        nve, exact = c['median']['nve'], c['median']['exact']
        extra = exact['ms_per_step'] - nve['ms_per_step']
        per_rank = c['natoms'] / c['ranks']
        setup = c['setup_median_seconds']
        model_rows.append([
            c['label'], _ms(extra), f'{1e6 * extra / per_rank:.0f}',
            f"{exact['loop_ms_per_step'] - nve['loop_ms_per_step']:.3g}",
            f"{exact['clean_per_step']:.3f} "
            f"({exact['clean_recomputations']}/{exact['steps']})",
            f"{1e3 * setup['exact']:.0f} / {1e3 * setup['nve']:.0f}",
            f"{1e3 * setup['exact'] * exact['clean_per_step']:.2g}",
            f"{1e6 * c['reduce_median_seconds_per_call']:.1f}",
            _power_of_two(c['velocity_quantum'])])
    lines += [
        '', '### Costs for a scaling model', '',
        "The exact path's own work per step (exact minus fix nve, wall "
        'time; also per atom of a rank, and in loop time only); clean '
        'recomputations per step over all measured blocks; a `run 0` setup '
        'on each instance (median; on the exact one it sorts atoms into '
        'its fine bins, as a clean recomputation does) and what it adds per '
        'step at the measured clean rate; one `rev.world.max(0.0)`, the '
        'MPI maximum every exact step makes (median over blocks of 1000 '
        'calls; on 1 rank no MPI call is made); the velocity quantum '
        '(Å/ps) chosen by default.', '',
        markdown_table(
            ['case', 'extra (ms/step)', 'extra (ns per atom of a rank)',
             'extra, loop time (ms/step)', 'clean per step',
             'run 0: exact / nve (ms)', 'clean cost (ms/step)',
             'MPI max (µs/call)', 'velocity quantum'], model_rows)]
    return '\n'.join(lines)
