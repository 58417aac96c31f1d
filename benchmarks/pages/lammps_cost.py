"""ReversibleLammps, compiled and Python paths, against LAMMPS's fix nve.

Measured by benchmarks/lammps_cost.py; the values also fill docs/lammps.md.
"""

from __future__ import annotations

from . import Spec, block, figure, markdown_table

PLOT = 'lammps_cost.png'

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


def ratio(case, name, key='ms_per_step'):
    """Exact over reference, medians over blocks of M steps."""
    m, reference = case['median'], case['integrators'][name]['reference']
    return m[name][key] / m[reference][key]


def long_ratio(case, name, key='cpu'):
    """Exact over reference per step of a long run (the per-run cost
    removed; lammps_cost.long_run_medians), CPU time by default."""
    m = case['long_run']
    reference = case['integrators'][name]['reference']
    return (m[name][f'{key}_ms_per_step']
            / m[reference][f'{key}_ms_per_step'])


def goal_cases(results):
    return [c for c in results['cases']
            if c['natoms'] >= results['goal_min_atoms']]


def _ms(value):
    return f'{value:.3g}' if abs(value) < 100 else f'{value:.0f}'


def _range(values, fmt):
    low, high = min(values), max(values)
    return fmt(low) if fmt(low) == fmt(high) else \
        f'{fmt(low)} to {fmt(high)}'


# -- the plot ------------------------------------------------------------------

def plot(results, figures):
    """Exact over reference, CPU time per step of a long run, against the
    number of atoms."""
    with figure(figures / PLOT, 1, (7, 5.5)) as (plt, fig, ax):
        cases = results['cases']
        colours = plt.rcParams['axes.prop_cycle'].by_key()['color']
        for colour, (name, _) in zip(colours, exact_names(cases[0])):
            for ranks, marker in ((1, 'o'), (2, 's')):
                for system, fill in (('argon', True), ('copper', False)):
                    chosen = sorted((c for c in cases if c['ranks'] == ranks
                                     and c['system'] == system),
                                    key=lambda c: c['natoms'])
                    if not chosen:
                        continue
                    ax.plot([c['natoms'] for c in chosen],
                            [long_ratio(c, name) for c in chosen],
                            marker + '-', color=colour, lw=0.8,
                            mfc=colour if fill else 'none',
                            label=f"{label(cases[0], name)}: "
                                  f"{'Ar LJ' if system == 'argon' else 'Cu EAM'}"
                                  f", {ranks} rank{'s' if ranks > 1 else ''}")
        ax.axhline(results['goal_ratio'], color='k', lw=0.8, ls=':',
                   label=f"goal ≤ {results['goal_ratio']:g} "
                         f"(N ≥ {results['goal_min_atoms']:,})")
        ax.axhline(1.0, color='grey', lw=0.5)
        ax.set_xscale('log')
        ax.set_xlabel('number of atoms')
        ax.set_ylabel('exact / fix nve, CPU time per step of a long run')
        ax.set_title('Time per step relative to fix nve')
        ax.legend(fontsize=6, ncol=2, loc='lower center',
                  bbox_to_anchor=(0.5, -0.45))


# -- tables and values ---------------------------------------------------------

def goal_table(results):
    """Each exact integrator against its reference over the cases with at
    least ``goal_min_atoms`` atoms (all, in quick mode): the ratios' ranges."""
    cases, first = goal_cases(results) or results['cases'], results['cases'][0]
    goals = results.get('goal_ratios', {'compiled': results['goal_ratio']})
    rows = []
    for name in (n for n in goals if n in first['integrators']):
        def spread(ratios):
            return _range([ratios(c) for c in cases], lambda r: f'{r:.3f}')
        rows.append([
            label(first, name), label(first, first['integrators'][name][
                'reference']), f'{goals[name]:.2f}', len(cases),
            spread(lambda c: long_ratio(c, name)),
            max(cases, key=lambda c: long_ratio(c, name))['label'],
            spread(lambda c: ratio(c, name, 'cpu_ms_per_step')),
            spread(lambda c: ratio(c, name)),
            spread(lambda c: ratio(c, name, 'loop_ms_per_step')),
            spread(lambda c: long_ratio(c, name, 'wall'))])
    return markdown_table(
        ['exact path', 'reference', 'goal (×)', 'cases',
         'CPU, long run (×)', 'worst case', 'CPU, blocks of M (×)',
         'wall, blocks of M (×)', "LAMMPS's loop time (×)",
         'wall, long run (×)'], rows)


def cost_table(results):
    """Per case: each instance's wall / CPU ms per step; each exact path's
    ratios to its reference; the worst block spread."""
    first = results['cases'][0]
    header = ['case', 'M (steps per block)', 'load average'] + [
        f'{label(first, name)}: wall / CPU (ms/step)'
        for name in reference_names(first)]
    for name, reference in exact_names(first):
        ref = label(first, reference)
        header += [f'{label(first, name)}: wall / CPU (ms/step)',
                   f'/ {ref}: wall / CPU', f'/ {ref}: CPU, long run']

    def wall_cpu(times):
        return f"{_ms(times['ms_per_step'])} / {_ms(times['cpu_ms_per_step'])}"
    rows = []
    for c in results['cases']:
        m = c['median']
        before, after = c['load_average']  # 1-minute, around the case
        row = [c['label'], c['steps'], f'{before[0]:.1f}-{after[0]:.1f}'] + [
            wall_cpu(m[name]) for name in reference_names(c)]
        for name, _ in exact_names(c):
            row += [wall_cpu(m[name]), f'{ratio(c, name):.3f} / '
                    f"{ratio(c, name, 'cpu_ms_per_step'):.3f}",
                    f'**{long_ratio(c, name):.3f}**']
        rows.append(row + [
            f"{max(m[n]['spread'] for n in c['integrators']):.0%}"])
    return markdown_table(header + ['block spread'], rows)


def scale_table(results):
    """The study lammps_scale: per size and rank count, fix nve's and the
    compiled fix's CPU time per step of a long run and their ratio."""
    scale = results.get('scale')
    if not scale:
        return 'Not measured: `python benchmarks/run_all.py --only lammps_scale`.'
    rows = []
    for c in scale['costs']:
        long = c['long_run']
        before, after = c['load_average']
        rows.append([
            f"{c['natoms']:,}", c['ranks'], c['steps'],
            f'{before[0]:.1f}-{after[0]:.1f}',
            _ms(long['nve']['cpu_ms_per_step']),
            _ms(long['compiled']['cpu_ms_per_step']),
            f"**{long_ratio(c, 'compiled'):.3f}**",
            f"{long_ratio(c, 'compiled', 'wall'):.3f}",
            f"{ratio(c, 'compiled', 'cpu_ms_per_step'):.3f}",
            c['median']['compiled']['clean_recomputations']])
    return markdown_table(
        ['argon atoms', 'ranks', 'M (steps per block)', 'load average',
         'fix nve: CPU, long run (ms/step)',
         'compiled: CPU, long run (ms/step)', 'compiled / fix nve: CPU, '
         'long run (×)', 'wall, long run (×)', 'CPU, blocks of M (×)',
         'steps recomputed (in the blocks)'], rows)


def scale_values(results):
    """The prose's numbers of the study lammps_scale's run out and back."""
    scale = results.get('scale')
    if not scale:
        return {}
    r = scale['reversal']
    legs = r['legs'].values()
    recomputed = sum(leg['recomputed_steps'] for leg in legs)
    seconds = sum(leg['recompute_seconds'] for leg in legs)
    wall = sum(leg['wall_seconds'] for leg in legs)
    return {'scale_natoms': f"{r['natoms']:,}", 'scale_ranks': r['ranks'],
            'scale_steps': r['steps'],
            'scale_recomputed': recomputed,
            'scale_atoms': sum(leg['recomputed_atoms'] for leg in legs),
            'scale_share': f'{100 * seconds / wall:.2g}%',
            'scale_recompute_ms': f'{1e3 * seconds / max(recomputed, 1):.2g}',
            'scale_wall': f'{wall:.0f}',
            'scale_bits': f"{r['velocity_bits']:.1f}",
            'scale_quantum': repr(r['velocity_quantum']),
            'scale_landed': ('every atom on its start, bit for bit'
                             if r['atoms_off_anchor'] == 0 else
                             f"{r['atoms_off_anchor']} atoms OFF their start"),
            'scale_modify': '; '.join(
                f"{_ms(c['median']['compiled']['breakdown_ms_per_step']['Modify'])}"
                f" against {_ms(c['median']['nve']['breakdown_ms_per_step']['Modify'])}"
                f" ms at {c['natoms']:,} atoms on {c['ranks']}"
                for c in scale['costs']),
            'scale_pair_share': _range(
                [c['median']['nve']['breakdown_ms_per_step']['Pair']
                 / c['median']['nve']['loop_ms_per_step']
                 for c in scale['costs']],
                lambda v: f'{100 * v:.0f}%'),
            'scale_ratios': _range([long_ratio(c, 'compiled')
                                    for c in scale['costs']],
                                   lambda v: f'{v:.3f}')}


def model_numbers(case, name):
    """The exact path ``name``'s costs in ``case``, for the scaling model."""
    reference = case['integrators'][name]['reference']
    per_rank = case['natoms'] / case['ranks']
    setup = case['setup_median_seconds']
    return {
        'long_extra_cpu_ns_per_atom': 1e6 * (
            case['long_run'][name]['cpu_ms_per_step']
            - case['long_run'][reference]['cpu_ms_per_step']) / per_rank,
        'long_reference_cpu_ns_per_atom': 1e6 * case['long_run'][
            reference]['cpu_ms_per_step'] / per_rank,
        'run_cpu_ms': case['long_run'][name]['cpu_ms_per_run'],
        'reference_run_cpu_ms': case['long_run'][reference][
            'cpu_ms_per_run'],
        'setup_in_steps': 1e3 * setup[name]
        / case['median'][reference]['ms_per_step']}


def values(results):
    """The prose's numbers: ranges over cases, as text."""
    cases, goal = results['cases'], goal_cases(results)
    single = [c for c in cases if c['ranks'] == 1]
    # The large cases, where the per-atom work dominates; quick mode has
    # only small ones.
    one = [c for c in single if c['natoms'] >= results['goal_min_atoms']] \
        or single
    two = [c for c in cases if c['ranks'] > 1]
    out = {'loads': _range([c['load_average'][i][0] for c in cases
                            for i in (0, 1)], lambda v: f'{v:.1f}'),
           'instances': ', '.join(f'`{label(cases[0], n)}`'
                                  for n in cases[0]['integrators']),
           'rounds': cases[0]['rounds'],
           'lammps_version': cases[0]['lammps_version'],
           'sizes': _range([c['natoms'] for c in one], lambda n: f'{n:,}'),
           'modify': _range([c['median']['compiled']['breakdown_ms_per_step']
                             .get('Modify', 0.0)
                             / c['median']['compiled']['ms_per_step']
                             for c in goal] or [0], lambda r: f'{100 * r:.1f}%'),
           'reduce_us': _range([c['reduce_median_seconds_per_call'] * 1e6
                                for c in two] or [0], lambda v: f'{v:.1f}'),
           'ranks': max((c['ranks'] for c in two), default=1),
           'setup_steps': _range([model_numbers(c, 'compiled')[
               'setup_in_steps'] for c in cases], lambda v: f'{v:.1f}')}
    for system in ('argon', 'copper'):
        out[f'nve_{system}'] = _range(
            [model_numbers(c, 'compiled')['long_reference_cpu_ns_per_atom']
             for c in one if c['system'] == system] or [0],
            lambda v: f'{v:.0f}')
    for n in ('compiled', 'python'):
        out[f'pair_{n}'] = _range(
            [c['median'][n]['breakdown_ms_per_step']['Pair']
             / c['median']['nve']['breakdown_ms_per_step']['Pair'] - 1
             for c in (goal or cases)], lambda e: f'{e:+.0%}')
        numbers = [model_numbers(c, n) for c in one]
        out[f'extra_{n}'] = _range(
            [x['long_extra_cpu_ns_per_atom'] for x in numbers],
            lambda v: f'{v:.0f}')
        out[f'run_{n}'] = _range(
            [x['run_cpu_ms'] - x['reference_run_cpu_ms'] for x in numbers],
            lambda v: f'{v:.0f}')
        out[f'clean_{n}'] = sum(c['median'][n]['clean_recomputations']
                                for c in cases)
        out[f'steps_{n}'] = sum(c['median'][n]['steps'] for c in cases)
    out.update(scale_values(results))
    return out


SPEC = Spec(
    'Exact runs inside LAMMPS',
    blocks={'costs-goal': block(goal_table),
            'costs': block(cost_table),
            'scale': block(scale_table)},
    plots=(plot,), values=values)
