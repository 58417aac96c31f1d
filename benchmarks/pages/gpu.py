"""PyTorch models on a GPU (or, where none was found, the same paths on the
CPU): measured by benchmarks/gpu.py."""

from __future__ import annotations

from . import Spec, block, markdown_table


def _ms(seconds):
    return f'{seconds * 1e3:.3g}'


def step_table(results):
    if 'skipped' in results:
        return f"Not measured: {results['skipped']}."
    return markdown_table(
        ['device', 'atoms', "force_purity chosen ('auto')", 'reversible (ms)',
         'VelocityVerlet (ms)', 'reversible / VelocityVerlet',
         'spread of rounds'],
        [[results['device_name'], c['n_atoms'], c['force_purity'],
          _ms(c['median_seconds']['reversible']),
          _ms(c['median_seconds']['velocity_verlet']), f"{c['ratio']:.3f}",
          f"{max(c['spread'].values()):.0%}"]
         for c in results['per_step']])


def calls_table(results):
    if 'skipped' in results:
        return ''
    return markdown_table(
        ['atoms', 'edges', 'force call (ms)', 'product / force',
         'list, skin hit / force', 'list, fresh / force',
         'deterministic / default kernels'],
        [[c['n_atoms'], c['n_edges'], _ms(c['seconds']['force']),
          f"{c['over_force']['product']:.2f}",
          f"{c['over_force']['list_skin_hit']:.3f}",
          f"{c['over_force']['list_fresh']:.2f}",
          f"{c['deterministic_over_default']:.3f}"]
         for c in results['calls']])


def memory_table(results):
    if 'skipped' in results:
        return ''
    memory = results['memory']
    rows = []
    for p in memory['points']:
        growth = (p['max_rss_bytes'] - p['max_rss_before_bytes']) / 2**20
        rows.append([p['steps'], f"{p['seconds']:.1f}", f'{growth:.1f}',
                     f"{p['cuda_peak_bytes'] / 2**20:.1f}"
                     if 'cuda_peak_bytes' in p else '-'])
    return markdown_table(
        ['steps out and retraced', 'seconds', 'peak RSS growth (MiB)',
         'CUDA peak allocated (MiB)'], rows)


def mace_table(results):
    if 'skipped' in results:
        return ''
    rows = []
    for c in results['mace']:
        if 'skipped' in c:
            rows.append([c['dtype'], '-', f"not measured: {c['skipped']}",
                         '-', '-', '-'])
            continue
        purity = c['force_purity']
        mode = purity['mode'] + (f" ({purity['force_noise']:.2g} eV/Å)"
                                 if 'force_noise' in purity else '')
        if 'DeterministicKernels' in c.get('holds', ()):
            mode += ', deterministic kernels held'
        rows.append([c['dtype'], c['n_atoms'], mode,
                     c['clean_recomputations']
                     if c['clean_recomputations'] is not None else '-',
                     'yes' if c['exact'] else 'NO', f"{c['ratio']:.3f}"])
    return markdown_table(
        ['dtype', 'atoms', "force_purity chosen ('auto')",
         'clean recomputations', 'out and back bit for bit',
         'reversible / VelocityVerlet'], rows)


def neighbours_table(results):
    study = results.get('neighbours')
    if study is None:
        return ('*Not measured yet: `python benchmarks/run_all.py --only '
                'device_neighbours`.*')
    names = (('numpy_fresh', 'numpy, fresh (8 Å)'),
             ('numpy_fresh_with_skin', 'numpy, fresh (9 Å)'),
             ('torch_fresh_with_skin', 'torch, fresh (9 Å)'),
             ('numpy_skin_hit', 'numpy, skin hit'),
             ('torch_skin_hit', 'torch, skin hit'))
    return markdown_table(
        ['device', 'atoms', 'pairs', 'candidates kept']
        + [f'{label} (ms)' for _, label in names],
        [[c['device'], c['n_atoms'], c['n_pairs'], c['n_candidates']]
         + [_ms(c['median_seconds'][key]) for key, _ in names]
         for c in study['cases']])


SPEC = Spec(
    'PyTorch models on a GPU',
    blocks={'steps': block(step_table), 'calls': block(calls_table),
            'memory': block(memory_table), 'mace': block(mace_table),
            'neighbours': block(neighbours_table)},
    values=lambda results: {'rounds': results['per_step'][0]['rounds']}
    if 'per_step' in results else {})
