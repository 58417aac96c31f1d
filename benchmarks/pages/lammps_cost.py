"""ReversibleLammps, compiled and Python paths, against LAMMPS's fix nve.

Measured by benchmarks/lammps_cost.py, whose docstring gives the method.
Besides its section of docs/benchmarks.md this module writes the numbers
of docs/lammps.md's cost and scaling sections (``DOC_BLOCKS``).
"""

from __future__ import annotations

import math

from . import markdown_table, pyplot

TITLE = 'Exact runs inside LAMMPS'
PLOT = 'lammps_cost.png'

#: Timer sections shown, in LAMMPS's order; the rest go to 'other'.
SHOWN_SECTIONS = ('Pair', 'Neigh', 'Comm', 'Modify')


# -- what a case measured ----------------------------------------------------

def exact_names(case):
    """The exact integrators of a case, each with its reference."""
    return [(name, about['reference'])
            for name, about in case['integrators'].items()
            if about['reference'] is not None]


def reference_names(case):
    """LAMMPS's own integrators of a case, which the exact ones are
    measured against."""
    return [name for name, about in case['integrators'].items()
            if about['reference'] is None]


def label(case, name):
    return case['integrators'][name]['label']


def ratio(case, name, reference=None, cpu=False):
    m = case['median']
    reference = reference or case['integrators'][name]['reference']
    key = 'cpu_ms_per_step' if cpu else 'ms_per_step'
    return m[name][key] / m[reference][key]


def long_ratio(case, name, key='cpu'):
    """Exact over reference per step of a long run (the per-run cost
    removed; lammps_cost.long_run_medians), CPU time by default."""
    m = case['long_run']
    reference = case['integrators'][name]['reference']
    return (m[name][f'{key}_ms_per_step']
            / m[reference][f'{key}_ms_per_step'])


def loop_ratio(case, name):
    m = case['median']
    reference = case['integrators'][name]['reference']
    return m[name]['loop_ms_per_step'] / m[reference]['loop_ms_per_step']


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


def load(case):
    """The 1-minute load average before and after the case, as text."""
    before, after = case['load_average']
    return f'{before[0]:.1f}-{after[0]:.1f}'


def loads(results):
    values = [c['load_average'][i][0] for c in results['cases']
              for i in (0, 1)]
    return min(values), max(values)


def _ms(value):
    return f'{value:.3g}' if abs(value) < 100 else f'{value:.0f}'


def _power_of_two(value):
    return f'2^{math.frexp(value)[1] - 1}'


def _range(values, fmt):
    low, high = min(values), max(values)
    return fmt(low) if fmt(low) == fmt(high) else \
        f'{fmt(low)} to {fmt(high)}'


def _atoms(case):
    return f"{case['natoms']:,}"


# -- the plot ------------------------------------------------------------------

def plot(results, figures):
    plt = pyplot()
    fig, (left, right) = plt.subplots(1, 2, figsize=(12, 5.5))
    cases = results['cases']
    names = exact_names(cases[0])
    colours = plt.rcParams['axes.prop_cycle'].by_key()['color']
    for k, (name, _) in enumerate(names):
        for ranks, marker in ((1, 'o'), (2, 's')):
            for system, fill in (('argon', True), ('copper', False)):
                chosen = sorted((c for c in cases if c['ranks'] == ranks
                                 and c['system'] == system),
                                key=lambda c: c['natoms'])
                if not chosen:
                    continue
                left.plot([c['natoms'] for c in chosen],
                          [long_ratio(c, name) for c in chosen],
                          marker + '-',
                          color=colours[k], lw=0.8,
                          mfc=colours[k] if fill else 'none',
                          label=f"{label(cases[0], name)}: "
                                f"{'Ar LJ' if system == 'argon' else 'Cu EAM'}"
                                f", {ranks} rank{'s' if ranks > 1 else ''}")
    left.axhline(results['goal_ratio'], color='k', lw=0.8, ls=':',
                 label=f"goal ≤ {results['goal_ratio']:g} "
                       f"(N ≥ {results['goal_min_atoms']:,})")
    left.axhline(1.0, color='grey', lw=0.5)
    left.set_xscale('log')
    left.set_xlabel('number of atoms')
    left.set_ylabel('exact / fix nve, CPU time per step of a long run')
    left.set_title('Time per step relative to fix nve')
    left.legend(fontsize=6, ncol=2, loc='lower center',
                bbox_to_anchor=(0.5, -0.45))

    # Per-step time of each case, every instance, stacked by where it
    # goes, in units of fix nve's step.
    instances = list(cases[0]['integrators'])
    width = len(instances) + 1
    ticks, top = [], 0.0
    for i, c in enumerate(cases):
        unit = c['median']['nve']['ms_per_step']
        for j, name in enumerate(instances):
            x = width * i + j
            bottom = 0.0
            for colour, (part, value) in zip(colours,
                                             breakdown(c, name).items()):
                right.bar(x, value / unit, bottom=bottom, color=colour,
                          label=part if i == 0 and j == 0 else None,
                          edgecolor='k' if j else None, linewidth=0.5,
                          hatch='//' if j == 2 else None)
                bottom += value / unit
            top = max(top, bottom)
        ticks.append((width * i + (len(instances) - 1) / 2,
                      c['label'].replace(', ', '\n')
                      .replace(f" {c['natoms']}", f"\n{c['natoms']}")))
    right.set_xticks([x for x, _ in ticks])
    right.set_xticklabels([t for _, t in ticks], fontsize=5)
    right.set_ylabel("time per step / fix nve's")
    right.set_title('Where a step goes: ' + ', '.join(
        label(cases[0], n) for n in instances) + ' (left to right)',
        fontsize=9)
    right.set_ylim(0, 1.3 * top)
    right.legend(fontsize=7, loc='upper left', ncol=3)
    fig.tight_layout()
    fig.savefig(figures / PLOT, dpi=110)
    plt.close(fig)


# -- sentences and tables ----------------------------------------------------

def goal_sentences(results):
    """One goal sentence per exact integrator that has a goal."""
    goals = results.get('goal_ratios', {'compiled': results['goal_ratio']})
    cases = results['cases']
    return ' '.join(goal_sentence(results, name) for name in goals
                    if cases and name in cases[0]['integrators'])


def goal_sentence(results, name='compiled'):
    cases = goal_cases(results)
    goal = results.get('goal_ratios', {}).get(name, results['goal_ratio'])
    n_min = results['goal_min_atoms']
    what = label(results['cases'][0], name) if results['cases'] else name
    reference = (label(results['cases'][0], results['cases'][0][
        'integrators'][name]['reference']) if results['cases'] else 'fix nve')
    if not cases:
        return (f'The goal ({what} within {goal:.2f}x of {reference} per '
                f'step at N ≥ {n_min:,}) was not measured here: no case has '
                'that many atoms.')

    def spread(values):
        return _range(values, lambda r: f'{r:.3f}')

    long_cpu = [long_ratio(c, name) for c in cases]
    worst = max(cases, key=lambda c: long_ratio(c, name))
    met = all(r <= goal for r in long_cpu)
    return (f"**Goal {'met' if met else 'not met'}** ({what} within "
            f'{goal:.2f}x of {reference} per step at N ≥ {n_min:,}, '
            'judged on CPU time per step of a long run, the number load '
            f'from other processes disturbs least): {spread(long_cpu)}x '
            f'over {len(cases)} cases (worst: {worst["label"]}). In blocks '
            f'of M steps, each paying one run\'s setup: '
            f'{spread([ratio(c, name, cpu=True) for c in cases])}x in CPU '
            f'time, {spread([ratio(c, name) for c in cases])}x in wall '
            'time, '
            f'{spread([loop_ratio(c, name) for c in cases])}x in LAMMPS\'s '
            'loop time (wall time without the setup). Wall time per step '
            'of a long run: '
            f"{spread([long_ratio(c, name, 'wall') for c in cases])}x.")


def cost_rows(results):
    rows = []
    for c in results['cases']:
        m = c['median']
        row = [c['label'], c['steps'], load(c)] + [
            f"{_ms(m[name]['ms_per_step'])} / "
            f"{_ms(m[name]['cpu_ms_per_step'])}"
            for name in reference_names(c)]
        for name, _ in exact_names(c):
            row += [f"{_ms(m[name]['ms_per_step'])} / "
                    f"{_ms(m[name]['cpu_ms_per_step'])}",
                    f'{ratio(c, name):.3f} / '
                    f'{ratio(c, name, cpu=True):.3f}',
                    f'**{long_ratio(c, name):.3f}**']
        row.append(f"{max(m[n]['spread'] for n in c['integrators']):.0%}")
        rows.append(row)
    return rows


def cost_header(results):
    first = results['cases'][0]
    header = ['case', 'M (steps per block)', 'load average'] + [
        f'{label(first, name)}: wall / CPU (ms/step)'
        for name in reference_names(first)]
    for name, reference in exact_names(results['cases'][0]):
        header += [f'{label(results["cases"][0], name)}: wall / CPU '
                   '(ms/step)',
                   f'/ {label(results["cases"][0], reference)}: wall / CPU',
                   f'/ {label(results["cases"][0], reference)}: CPU, '
                   'long run']
    return header + ['block spread']


def strong_rows(results):
    strong = {}
    for c in uses(results, 'strong'):
        strong.setdefault((c['system'], c['natoms']), {})[c['ranks']] = c
    rows = []
    for (system, natoms), by_ranks in strong.items():
        if 1 not in by_ranks or len(by_ranks) < 2:
            continue
        one = by_ranks[1]
        for ranks, c in sorted(by_ranks.items()):
            if ranks == 1:
                continue
            row = [one['label'].split(',')[0], ranks]
            for name in c['integrators']:
                speedup = (one['median'][name]['ms_per_step']
                           / c['median'][name]['ms_per_step'])
                row.append(f'{speedup:.2f} ({speedup / ranks:.0%})')
            rows.append(row + [f"{ratio(one, n):.3f} → {ratio(c, n):.3f}"
                               for n, _ in exact_names(c)])
    return rows


def weak_rows(results):
    weak = sorted(uses(results, 'weak'), key=lambda c: c['ranks'])
    if len(weak) < 2 or weak[0]['ranks'] != 1:
        return []
    one = weak[0]
    return [[c['label'], f"{c['natoms'] // c['ranks']:,}"]
            + [f"{one['median'][n]['ms_per_step'] / c['median'][n]['ms_per_step']:.0%}"
               for n in c['integrators']]
            + [f'{ratio(c, n):.3f}' for n, _ in exact_names(c)]
            for c in weak]


def model_numbers(case, name):
    """The exact path ``name``'s costs in ``case``, for the scaling model."""
    m = case['median']
    reference = case['integrators'][name]['reference']
    exact, ref = m[name], m[reference]
    per_rank = case['natoms'] / case['ranks']
    setup = case['setup_median_seconds']
    return {
        'extra_ms': exact['ms_per_step'] - ref['ms_per_step'],
        'extra_cpu_ms': exact['cpu_ms_per_step'] - ref['cpu_ms_per_step'],
        'extra_ns_per_atom': 1e6 * (exact['ms_per_step']
                                    - ref['ms_per_step']) / per_rank,
        'extra_cpu_ns_per_atom': 1e6 * (exact['cpu_ms_per_step']
                                        - ref['cpu_ms_per_step']) / per_rank,
        'long_extra_cpu_ns_per_atom': 1e6 * (
            case['long_run'][name]['cpu_ms_per_step']
            - case['long_run'][reference]['cpu_ms_per_step']) / per_rank,
        'long_reference_cpu_ns_per_atom': 1e6 * case['long_run'][
            reference]['cpu_ms_per_step'] / per_rank,
        'run_cpu_ms': case['long_run'][name]['cpu_ms_per_run'],
        'reference_run_cpu_ms': case['long_run'][reference][
            'cpu_ms_per_run'],
        'reference_ns_per_atom': 1e6 * ref['ms_per_step'] / per_rank,
        'reference_cpu_ns_per_atom': 1e6 * ref['cpu_ms_per_step'] / per_rank,
        'extra_loop_ms': exact['loop_ms_per_step'] - ref['loop_ms_per_step'],
        'clean_per_step': exact['clean_per_step'],
        'clean': exact['clean_recomputations'],
        'steps': exact['steps'],
        'setup_ms': 1e3 * setup[name],
        'reference_setup_ms': 1e3 * setup[reference],
        'setup_in_steps': 1e3 * setup[name] / ref['ms_per_step'],
        'clean_ms_per_step': 1e3 * setup[name] * exact['clean_per_step'],
        'reduce_us': 1e6 * case['reduce_median_seconds_per_call'],
        'velocity_quantum': case['exact'][name]['velocity_quantum'],
    }


def model_rows(results):
    rows = []
    for c in results['cases']:
        for name, _ in exact_names(c):
            n = model_numbers(c, name)
            rows.append([
                c['label'], label(c, name),
                f"{_ms(n['extra_ms'])} / {_ms(n['extra_cpu_ms'])}",
                f"{n['extra_ns_per_atom']:.0f} / "
                f"{n['extra_cpu_ns_per_atom']:.0f} / "
                f"{n['long_extra_cpu_ns_per_atom']:.0f}",
                f"{n['run_cpu_ms']:.0f} / {n['reference_run_cpu_ms']:.0f}",
                f"{n['extra_loop_ms']:.3g}",
                f"{n['clean_per_step']:.4f} ({n['clean']}/{n['steps']})",
                f"{n['setup_ms']:.0f} / {n['reference_setup_ms']:.0f}",
                f"{n['clean_ms_per_step']:.2g}",
                f"{n['reduce_us']:.1f}" if c['ranks'] > 1 else '-',
                _power_of_two(n['velocity_quantum'])])
    return rows


def markdown(results):
    cases = results['cases']
    low, high = loads(results)
    instances = ', '.join(f'`{label(cases[0], n)}`'
                          for n in cases[0]['integrators'])
    lines = [
        'The same input in one LAMMPS instance per integrator '
        f'({instances}), all in one process per rank; blocks of the same '
        'number of steps M rotate among them, '
        f"{cases[0]['rounds']} of each after a warm-up block, and the "
        'medians per step are compared (`benchmarks/lammps_cost.py`; time '
        f"step {results['timestep_ps']!r} ps, LAMMPS "
        f"{cases[0]['lammps_version']}). Machine: {results['cpu']}, "
        f"{results['cores']} cores, shared with other work: 1-minute load "
        f'average {low:.1f} to {high:.1f} over the cases (per case in the '
        'table, before and after). Wall time is the slowest rank\'s, '
        'between MPI barriers; CPU time is `time.process_time()` of each '
        "rank during the run, the largest over the ranks, which another "
        "process's load does not inflate as much. Wall time per step "
        "includes the setup that starts every `run` and, on the exact "
        "side, its clean recomputations; LAMMPS's loop time leaves both "
        'out. Block spread: (slowest - fastest) / median block, the worst '
        'instance. A step of a long run is (median block of M steps - '
        'median block of 1 step) / (M - 1): without the setup each run '
        'starts with, which blocks of M pay once (and the exact path\'s '
        'sort into fine bins makes dearer).',
        '',
        goal_sentences(results),
        '',
        f'![exact against fix nve](benchmarks/{PLOT})',
        '',
        markdown_table(cost_header(results), cost_rows(results)),
        '',
        '### Where a step goes',
        '',
        "Milliseconds per step from LAMMPS's timer (average over ranks) in "
        'the block of median wall time; "outside loop" is wall time minus '
        'loop time: the setup of each run (and of each clean recomputation) '
        "and the Python around it. The compiled path is `fix "
        "reversible/nve`; the Python path's kick is a Python callback "
        "(`fix external`), its drift a `fix move` of atom-style variables "
        'and its halt a `fix halt`; all of them count under Modify.',
        '',
        markdown_table(
            ['case', 'integrator'] + list(breakdown(cases[0], 'nve'))
            + ['total'],
            [[c['label'], label(c, name)]
             + [_ms(v) for v in breakdown(c, name).values()]
             + [_ms(sum(breakdown(c, name).values()))]
             for c in cases for name in c['integrators']]),
        '',
        pair_sentence(results),
    ]
    if strong_rows(results):
        lines += [
            '', '### Strong scaling', '',
            'Speed-up in wall time per step from 1 rank to R ranks on the '
            'same system (parallel efficiency), and exact / fix nve at 1 '
            'and at R ranks.', '',
            markdown_table(['system', 'R']
                           + [f'{label(cases[0], n)} speed-up'
                              for n in cases[0]['integrators']]
                           + [f'{label(cases[0], n)} / fix nve, 1 → R'
                              for n, _ in exact_names(cases[0])],
                           strong_rows(results))]
    if weak_rows(results):
        lines += [
            '', '### Weak scaling', '',
            'The same number of atoms per rank; efficiency is the wall time '
            'per step on 1 rank over that on R ranks.', '',
            markdown_table(['case', 'atoms per rank']
                           + [f'{label(cases[0], n)} efficiency'
                              for n in cases[0]['integrators']]
                           + [f'{label(cases[0], n)} / fix nve'
                              for n, _ in exact_names(cases[0])],
                           weak_rows(results))]
    lines += [
        '', '### Costs for a scaling model', '',
        "Each exact path's own work per step (exact minus fix nve, wall "
        'and CPU time in blocks of M; also per atom of a rank, there and '
        'per step of a long run, and in loop time only); the CPU time of '
        'a run besides its steps (setup, and on the exact side the checks '
        'and fixes of `rev.run`; from blocks of one step); '
        'clean recomputations per step over all measured blocks; a `run 0` '
        'setup on the exact instance and on fix nve\'s (median; on the exact '
        'one it sorts atoms into its fine bins, as a clean recomputation '
        'does) and what it adds per step at the measured clean rate; one '
        'MPI maximum of one value (`rev.world.max(0.0)`, through ctypes: '
        "the Python path's per-step collective, and an upper bound on the "
        "compiled fix's `MPI_Allreduce`; median over blocks of "
        f"{cases[0]['reduce_calls']} calls; on 1 rank no MPI call is made); "
        'the velocity quantum (Å/ps) chosen by default.', '',
        markdown_table(
            ['case', 'path', 'extra: wall / CPU (ms/step)',
             'extra: wall / CPU / CPU of a long run (ns per atom of a '
             'rank)', 'CPU of a run besides its steps: exact / fix nve (ms)',
             'extra, loop time (ms/step)', 'clean per step',
             'run 0: exact / fix nve (ms)', 'clean cost (ms/step)',
             'MPI max (µs/call)', 'velocity quantum'], model_rows(results))]
    return '\n'.join(lines)


def pair_sentence(results):
    parts = []
    for name, reference in exact_names(results['cases'][0]):
        excess = [c['median'][name]['breakdown_ms_per_step']['Pair']
                  / c['median'][reference]['breakdown_ms_per_step']['Pair']
                  - 1 for c in results['cases']]
        parts.append(f"{label(results['cases'][0], name)}: "
                     f"{_range(excess, lambda e: f'{e:+.0%}')}")
    return ('Pair time per step (median over blocks) against fix nve on the '
            'same system, ' + '; '.join(parts) + '.')


# -- docs/lammps.md ----------------------------------------------------------

def _by(results, system, natoms, ranks):
    for c in results['cases']:
        if (c['system'], c['natoms'], c['ranks']) == (system, natoms, ranks):
            return c
    return None


def lammps_costs(stored):
    """The numbers of docs/lammps.md's "What it costs"."""
    results = stored['results']
    cases = results['cases']
    low, high = loads(results)
    rows = []
    for c in cases:
        m = c['median']
        rows.append([c['label'].replace('LJ ', '').replace('EAM ', '')
                     .replace(f"{c['natoms']}", _atoms(c)), load(c),
                     _ms(m['nve']['ms_per_step']),
                     _ms(m['compiled']['ms_per_step']),
                     f"{ratio(c, 'compiled'):.3f} / "
                     f"{ratio(c, 'compiled', cpu=True):.3f} / "
                     f"**{long_ratio(c, 'compiled'):.3f}**",
                     _ms(m['python']['ms_per_step']),
                     f"{ratio(c, 'python'):.2f} / "
                     f"{ratio(c, 'python', cpu=True):.2f} / "
                     f"**{long_ratio(c, 'python'):.2f}**"])
    goal = goal_cases(results)
    modify = [c['median']['compiled']['breakdown_ms_per_step'].get(
        'Modify', 0.0) / c['median']['compiled']['ms_per_step'] for c in goal]
    pair = {n: [c['median'][n]['breakdown_ms_per_step']['Pair']
                / c['median']['nve']['breakdown_ms_per_step']['Pair'] - 1
                for c in goal] for n in ('compiled', 'python')}
    lines = [
        f"Measured by `{stored['command']}` ({stored['wall_seconds']:.0f} s "
        f"on {results['cores']} cores of an {results['cpu']} VM shared with "
        f'other work, 1-minute load average {low:.1f} to {high:.1f}; the '
        'full tables are on the [benchmarks page](benchmarks.md)): the same '
        'input in three LAMMPS instances per process, under `fix nve`, the '
        'compiled exact path and the Python one, in rotating blocks, '
        'medians per step of wall time and of CPU time (the largest over '
        'ranks, which load from other processes inflates less; the load '
        'average before and after each case is in the table); argon '
        'under lj/cut 8.5 Å at 100 K and copper under eam at 600 K, time '
        f"step {results['timestep_ps']!r} ps.",
        '',
        markdown_table(['case', 'load average', 'fix nve (ms/step)',
                        'compiled (ms/step)',
                        'compiled / fix nve: wall / CPU / CPU, long run',
                        'Python (ms/step)',
                        'Python / fix nve: wall / CPU / CPU, long run'],
                       rows),
        '',
        'Milliseconds are wall time per step in blocks of M steps (the '
        'benchmarks page gives M per case); "long run" is CPU time per step '
        'without the setup that starts every run: (block of M - block of '
        'one step) / (M - 1), medians.',
        '',
        goal_sentences(results),
    ]
    if goal:
        lines += [
            '',
            "Where the time goes (LAMMPS's timer, the same cases): the "
            "compiled fix's drift, kick and guard count under Modify, "
            f"{_range(modify, lambda r: f'{100 * r:.1f}%')} of the compiled "
            'step; its Pair time is within '
            f"{_range(pair['compiled'], lambda e: f'{e:+.0%}')} of fix "
            "nve's, where the Python path's is "
            f"{_range(pair['python'], lambda e: f'{e:+.0%}')}: the Python "
            "path's variables (the velocities of its `fix move`, the flag "
            "of its `fix halt`) make LAMMPS tally energy and virial at every "
            'step, which the compiled fix does not ask for.']
    return '\n'.join(lines)


def lammps_scaling(stored):
    """The measured inputs of docs/lammps.md's scaling model."""
    results = stored['results']
    single = [c for c in results['cases'] if c['ranks'] == 1]
    # The large cases, where the per-atom work dominates; quick mode has
    # only small ones.
    one = [c for c in single if c['natoms'] >= results['goal_min_atoms']] \
        or single
    two = [c for c in results['cases'] if c['ranks'] > 1]
    sizes = _range([c['natoms'] for c in one], lambda n: f'{n:,}')

    def per_atom(system, key):
        values = [model_numbers(c, 'compiled')[key] for c in one
                  if c['system'] == system]
        return _range(values, lambda v: f'{v:.0f}') if values else '?'

    extra = {n: [model_numbers(c, n)['long_extra_cpu_ns_per_atom']
                 for c in one] for n in ('compiled', 'python')}
    run_cost = {n: [model_numbers(c, n)['run_cpu_ms']
                    - model_numbers(c, n)['reference_run_cpu_ms']
                    for c in one] for n in ('compiled', 'python')}
    reduce_us = [c['reduce_median_seconds_per_call'] * 1e6 for c in two]
    clean = {n: (sum(c['median'][n]['clean_recomputations']
                     for c in results['cases']),
                 sum(c['median'][n]['steps'] for c in results['cases']))
             for n in ('compiled', 'python')}
    setup_steps = [model_numbers(c, 'compiled')['setup_in_steps']
                   for c in results['cases']]
    ranks = max((c['ranks'] for c in two), default=1)
    return '\n'.join([
        '- **`fix nve`\'s own work**, per atom of a rank and step (CPU '
        f"time, 1 rank, {sizes} atoms): "
        f"{per_atom('argon', 'long_reference_cpu_ns_per_atom')} ns (argon, "
        "lj/cut 8.5 Å) and "
        f"{per_atom('copper', 'long_reference_cpu_ns_per_atom')}"
        ' ns (copper, eam), plus halo communication that grows as '
        '`n^(2/3)`.',
        "- **The exact path's local work**, exact minus `fix nve` in CPU "
        'time per atom of a rank and step of a long run, on the same '
        'cases: compiled '
        f"{_range(extra['compiled'], lambda v: f'{v:.0f}')} ns, Python "
        f"{_range(extra['python'], lambda v: f'{v:.0f}')} ns (each a "
        'difference of two measured times, which under load can come out '
        'negative). It does not depend on `P`. Each run costs more besides '
        "its steps (the exact path's checks, its fixes, and its setup's "
        'sort into fine bins): compiled '
        f"{_range(run_cost['compiled'], lambda v: f'{v:.0f}')} ms, Python "
        f"{_range(run_cost['python'], lambda v: f'{v:.0f}')} ms of CPU "
        'time per run on these cases.',
        '- **Collectives**: the compiled fix makes one `MPI_Allreduce` of '
        'one integer per step (the guard\'s verdict), the Python path an '
        "MPI maximum and `fix halt`'s own. One maximum of one value, called "
        f'from Python, took {_range(reduce_us, lambda v: f"{v:.1f}")} µs on '
        f'{ranks} ranks of this machine; a collective costs about '
        '`α log2 P`.',
        '- **Clean recomputations**: '
        f"{clean['compiled'][0]} in {clean['compiled'][1]:,} compiled steps "
        f"and {clean['python'][0]} in {clean['python'][1]:,} Python steps "
        'of the cases measured. Each costs a LAMMPS setup, measured at '
        f"{_range(setup_steps, lambda v: f'{v:.1f}')} compiled steps' "
        'time.',
    ])


#: docs pages this section writes numbers into, with the function that
#: renders each block: render.py replaces what lies between the block's
#: markers.
DOC_BLOCKS = {('lammps.md', 'costs'): lammps_costs,
              ('lammps.md', 'scaling'): lammps_scaling}
