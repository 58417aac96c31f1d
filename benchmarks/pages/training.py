"""Training through exact retraces: gradients against finite differences of
float runs, memory against steps beside plain autograd, time of a
gradient against the forward run.

Measured by benchmarks/studies/training.py, whose docstring gives the method.
"""

from __future__ import annotations

from . import Spec, block, figure, label, markdown_table

MEMORY_PLOT = 'training_memory.png'

LOSS_NAMES = {'rdf': 'g(r) loss', 'vacf': 'VACF loss',
              'msd': 'mean squared displacement'}


def plot(results, figures):
    with figure(figures / MEMORY_PLOT, 1, (7, 4), dpi=100) as (plt, fig, ax):
        memory = results['memory']
        for kind, legend, marker, color in (
                ('reversible', 'one epoch through backpropagate (loss=, '
                 'window=)', 'o-', 'C0'),
                ('autograd', 'plain PyTorch autograd through the steps',
                 's-', 'C3')):
            pts = memory['points'][kind]
            ax.loglog([p['steps'] for p in pts],
                      [p['max_rss_bytes'] / 2**20 for p in pts], marker,
                      color=color, label=legend)
        extra = memory['autograd_extrapolated_bytes']
        ax.loglog([int(n) for n in extra], [b / 2**20 for b in extra.values()],
                  ':', color='C3', label='autograd, extrapolated linearly')
        ax.grid(True, which='major', alpha=0.3)
        label(ax, 'steps', 'peak resident set size (MiB)',
              f"{memory['atoms']} argon atoms: peak memory of one gradient "
              '(a fresh process per point)')


def gradients_table(g):
    return markdown_table(
        ('loss', 'parameter', 'h / value', 'dL/dθ retrace',
         'dL/dθ finite difference', 'relative difference'),
        [(LOSS_NAMES[c['loss']], c['parameter'], f"{c['relative_step']:.0e}",
          f"{c['retrace']:.10g}", f"{c['finite_difference']:.10g}",
          f"{c['relative_error']:.1e}") for c in g['checks']])


def memory_table(memory):
    def growth(p):
        if p.get('rss_peak_bytes') is None:
            return ''
        return f"{(p['rss_peak_bytes'] - p['rss_before_bytes']) / 2**20:.1f}"

    rows = [(p['steps'], how, f"{p['max_rss_before_bytes'] / 2**20:.0f}",
             f"{p['max_rss_bytes'] / 2**20:.0f}", growth(p),
             f"{p['seconds']:.0f}")
            for kind, how in (('reversible', 'reversible retrace'),
                              ('autograd', 'plain autograd'))
            for p in memory['points'][kind]]
    rows += [(n, 'plain autograd, extrapolated', '', f"{b / 2**20:.0f}", '',
              '') for n, b in memory['autograd_extrapolated_bytes'].items()]
    measured = memory.get('measured')
    when = (f"Measured again by `{measured['command']}`, load average "
            f"{measured['load_average'][0]:.1f}.\n\n") if measured else ''
    return when + markdown_table(
        ('steps', 'how', 'peak before the run', 'peak',
         'growth during the run', 'seconds'), rows)


def time_table(time):
    return markdown_table(
        ('student', 'atoms', 'steps', 'parameters', 'forward (s)',
         'gradient (s)', 'gradient / forward', 'exact'),
        [(c['student'], c['atoms'], c['steps'], c['parameters'],
          f"{c['forward_seconds_median']:.2f}",
          f"{c['gradient_seconds_median']:.2f}", f"{c['ratio_median']:.2f}",
          'yes' if c['exact_return_every_round'] else 'NO')
         for c in time['cases']])


SPEC = Spec(
    'Training through exact retraces',
    blocks={'gradients': block(gradients_table, 'gradients'),
            'memory': block(memory_table, 'memory'),
            'time': block(time_table, 'time')},
    plots=(plot,),
    values=lambda results: {
        'exact_return': 'yes' if results['gradients']['exact_return']
        else 'NO',
        'autograd_mib_per_step':
            results['memory']['autograd_bytes_per_step'] / 2**20})
