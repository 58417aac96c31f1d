"""The sections that are a table or two, each measured by the
benchmarks/ script of its name."""

from __future__ import annotations

from . import Spec, block, markdown_table


def torch_tables(results):
    if 'skipped' in results:
        return f"Not measured: {results['skipped']}."
    cases = results['cases']
    rows = [[c['model'], c['n_atoms'], c['threads'], c['n_edges'],
             f"{c['force_cpu'] * 1e3:.3g}", f"{c['product_cpu'] * 1e3:.3g}",
             f"{c['product_ratio_cpu']:.2f}",
             f"{c['product_fresh_ratio_cpu']:.2f}",
             f"{c['product_ratio_wall']:.2f}"] for c in cases]
    return markdown_table(['model', 'atoms', 'threads', 'edges',
                           'force call (ms CPU)', 'product (ms CPU)',
                           'product / force', 'fresh / force',
                           'product / force (wall)'], rows)


def neighbour_table(results):
    return markdown_table(
        ['model', 'atoms', 'cut-off (Å)', 'edges', 'search (ms)',
         'with skin (ms)', "ASE's (ms)", 'ASE / search'],
        [[c['model'], c['n_atoms'], f"{c['cutoff']:g}", c['n_edges'],
          f"{c['neighbours_cpu'] * 1e3:.3g}",
          f"{c['neighbours_skin_cpu'] * 1e3:.3g}",
          f"{c['ase_neighbours_cpu'] * 1e3:.3g}",
          f"{c['ase_over_ours_cpu']:.1f}"]
         for c in results.get('cases', ()) if 'neighbours_cpu' in c])


def measured_commits(results):
    return [c['commit'] for c in results['commits']
            if c['commit'] not in results['skipped']]


def savings_table(results):
    if not results['cases']:
        return ('Skipped: the baseline commits '
                f"{', '.join(results['skipped'])} are not in this clone.")
    commits = measured_commits(results)
    rows = []
    for case in results['cases']:
        base = case['ms_per_step'][commits[0]]
        rows.append([case['case']] + [
            f"{case['ms_per_step'][c]:.3f} ({case['ms_per_step'][c] / base:.3f})"
            for c in commits] + [f"{case['spread']:.0%}"])
    return markdown_table(['case'] + commits + ['round spread'], rows)


def log2_cell(value):
    return '-' if value is None else f'2^{value:g}'


def full_precision_table(results):
    return markdown_table(
        ['system', 'calculator', 'noise median / max (eV/Å)',
         'quantum, pure', 'quantum, guarded (auto)',
         'quantum for 1% clean, measured bound',
         'band fraction at pure quantum', 'P(clean) per step at pure quantum',
         'clean recomputation (force calls)'],
        [[r['system'], r['calculator'],
          f"{r['noise_median']:.1e} / {r['noise_max']:.1e}",
          log2_cell(r['q_pure_log2']), log2_cell(r['q_guarded_log2']),
          log2_cell(r['q_measured_bound_log2']),
          f"{r['band_fraction_at_pure_quantum']:.2g}",
          f"{r['clean_per_step_at_pure_quantum']:.2g}",
          f"{r['clean_seconds'] / r['force_call_seconds']:.1f}"]
         for r in results['rows']])


def portable_table(results):
    """The force calls with the kernels before and now, in ms."""
    return markdown_table(
        ['calculator', 'atoms', 'before (ms)', 'now (ms)', 'ratio'],
        [[r['calculator'], r['n_atoms'], f"{r['old_seconds'] * 1e3:.3g}",
          f"{r['new_seconds'] * 1e3:.3g}",
          f"{r['new_seconds'] / r['old_seconds']:.2f}"]
         for r in results['forces']])


def force_noise_table(results):
    return markdown_table(
        ['calculator', 'system', 'max force difference per trial (eV/Å)',
         'force call (ms)', 'with a fresh neighbour list (ms)', 'ratio'],
        [[r['calculator'], r['system'],
          ', '.join(f'{d:.1e}' for d in r['max_force_difference']),
          f"{r['force_call_seconds'] * 1e3:.2f}",
          f"{r['fresh_list_seconds'] * 1e3:.2f}",
          f"{r['fresh_list_seconds'] / r['force_call_seconds']:.1f}"]
         for r in results['rows']])


def long_reversal_table(results):
    return (f"Ar{results['atoms']} at {results['temperature_K']:g} K, "
            f"{results['timestep_fs']:g} fs.\n\n" + markdown_table(
                ['scheme', 'N each way', 'back at start bit for bit',
                 'largest displacement at the turn (Å)', 'wall time (s)'],
                [[r['scheme'], f"{r['steps']:,}",
                  'yes' if r['exact'] else '**no**',
                  f"{r['largest_displacement_at_turn']:.2f}",
                  f"{r['seconds']:.0f}"] for r in results['runs']]))


SPECS = {
    'savings': Spec('Savings on the per-step path', blocks={
        'commits': block(lambda results: '\n'.join(
            f"- `{c['commit']}`: {c['change']}" for c in results['commits'])),
        'table': block(savings_table)}),
    'portable': Spec('Portable arithmetic',
                     blocks={'forces': block(portable_table)}),
    'force_noise': Spec('Force noise and rebuild cost',
                        blocks={'table': block(force_noise_table)}),
    'full_precision': Spec('Full precision under asap3: the options',
                           blocks={'table': block(full_precision_table)}),
    'long_reversal': Spec('Long round trips with ASE LennardJones',
                          blocks={'table': block(long_reversal_table)}),
    'torch_products': Spec(
        'PyTorch models: products and neighbour lists',
        blocks={'products': block(torch_tables),
                'neighbours': block(neighbour_table)},
        values=lambda results: {'rounds': results['cases'][0]['rounds']}),
}
