"""Training through exact retraces: gradients against finite differences of
float runs, memory against steps beside plain autograd, time of a
gradient against the forward run.

Measured by benchmarks/training.py, whose docstring gives the method.
"""

from __future__ import annotations

from . import markdown_table, pyplot

TITLE = 'Training through exact retraces'
MEMORY_PLOT = 'training_memory.png'

LOSS_NAMES = {'rdf': 'g(r) loss', 'vacf': 'VACF loss',
              'msd': 'mean squared displacement'}


def plot(results, figures):
    plt = pyplot()
    memory = results['memory']
    fig, ax = plt.subplots(figsize=(7, 4))
    for kind, label, marker, color in (
            ('reversible', 'one epoch through backpropagate (loss=, '
             'window=)', 'o-', 'C0'),
            ('autograd', 'plain PyTorch autograd through the steps',
             's-', 'C3')):
        pts = memory['points'][kind]
        ax.loglog([p['steps'] for p in pts],
                  [p['max_rss_bytes'] / 2**20 for p in pts], marker,
                  color=color, label=label)
    extra = memory['autograd_extrapolated_bytes']
    ax.loglog([int(n) for n in extra], [b / 2**20 for b in extra.values()],
              ':', color='C3', label='autograd, extrapolated linearly')
    ax.set_xlabel('steps')
    ax.set_ylabel('peak resident set size (MiB)')
    ax.grid(True, which='major', alpha=0.3)
    ax.legend(fontsize=8)
    ax.set_title(f"{memory['atoms']} argon atoms: peak memory of one "
                 'gradient (a fresh process per point)', fontsize=10)
    fig.tight_layout()
    fig.savefig(figures / MEMORY_PLOT, dpi=100)
    plt.close(fig)


def markdown(results) -> str:
    g = results['gradients']
    rows = [(LOSS_NAMES[c['loss']], c['parameter'],
             f"{c['relative_step']:.0e}", f"{c['retrace']:.10g}",
             f"{c['finite_difference']:.10g}", f"{c['relative_error']:.1e}")
            for c in g['checks']]
    s = g['student']
    memory = results['memory']
    rev, auto = memory['points']['reversible'], memory['points']['autograd']
    def growth(p):
        if p.get('rss_peak_bytes') is None:
            return ''
        return f"{(p['rss_peak_bytes'] - p['rss_before_bytes']) / 2**20:.1f}"

    mem_rows = [(p['steps'], 'reversible retrace',
                 f"{p['max_rss_before_bytes'] / 2**20:.0f}",
                 f"{p['max_rss_bytes'] / 2**20:.0f}", growth(p),
                 f"{p['seconds']:.0f}") for p in rev]
    mem_rows += [(p['steps'], 'plain autograd',
                  f"{p['max_rss_before_bytes'] / 2**20:.0f}",
                  f"{p['max_rss_bytes'] / 2**20:.0f}", growth(p),
                  f"{p['seconds']:.0f}") for p in auto]
    mem_rows += [(n, 'plain autograd, extrapolated', '',
                  f"{b / 2**20:.0f}", '', '')
                 for n, b in memory['autograd_extrapolated_bytes'].items()]
    measured = memory.get('measured')
    when = (f" (measured again by `{measured['command']}`, load average "
            f"{measured['load_average'][0]:.1f})") if measured else ''
    time_rows = [(c['student'], c['atoms'], c['steps'], c['parameters'],
                  f"{c['forward_seconds_median']:.2f}",
                  f"{c['gradient_seconds_median']:.2f}",
                  f"{c['ratio_median']:.2f}",
                  'yes' if c['exact_return_every_round'] else 'NO')
                 for c in results['time']['cases']]
    return f"""
The training loop of `examples/fit_rdf.py` ([Training](training.md)),
measured by `benchmarks/training.py`.

**Gradients against finite differences of float runs.** {g['atoms']}
argon atoms equilibrated at 94.4 K, then an NVE window of {g['steps']}
steps of 5 fs with a Lennard-Jones student (ε = {s['epsilon']} eV,
σ = {s['sigma']} Å, rc = {s['rc']} Å given), states observed every
{g['every']} steps.  The retrace (`ReversibleVerlet.backpropagate`, one per
loss, exact return: {'yes' if g['exact_return'] else 'NO'}) against
central differences of ASE `VelocityVerlet` runs from the same start with
ε ± h, σ ± h:

{markdown_table(('loss', 'parameter', 'h / value', 'dL/dθ retrace',
                 'dL/dθ finite difference', 'relative difference'), rows)}

The finite differences err by about h² (truncation) plus the float runs'
rounding over h; the smallest error over h is the agreement.

**Memory**{when} (peak resident set size of a fresh process per point,
MiB; {memory['atoms']} atoms, rc = 5.5 Å, g(r) every 100 steps).  The
retrace's peak at its longest run is {memory['reversible_largest_over_smallest']:.3f}
times its peak at its shortest.  The process's peak can be set by its
imports, which would hide a smaller growth: *growth* is the largest
resident size sampled every 10 ms during the run (forward and retrace)
less the resident size just before it.  Plain autograd grows by
{memory['autograd_bytes_per_step'] / 2**20:.3f} MiB per step (between its
shortest and longest runs here); its rows marked extrapolated are that
slope, not measured.

{markdown_table(('steps', 'how', 'peak before the run', 'peak',
                 'growth during the run', 'seconds'), mem_rows)}

![memory]({'benchmarks/' + MEMORY_PLOT})

**Time of a gradient against the forward run** (one epoch: the forward run
with g(r) observed every 50 steps, then one retrace with `loss=`,
`window=50` and the parameters; medians over rounds, forward and retrace
interleaved, every round back at the start bit for bit):

{markdown_table(('student', 'atoms', 'steps', 'parameters', 'forward (s)',
                 'gradient (s)', 'gradient / forward', 'exact'),
                time_rows)}
"""
