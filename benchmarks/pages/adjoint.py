"""Gradients by the reversible adjoint: memory against steps, and the cost
of a gradient in force evaluations and time.

Measured by benchmarks/adjoint.py, whose docstring gives the method.
"""

from __future__ import annotations

import numpy as np

from . import Spec, block, markdown_table, pyplot

MEMORY_PLOT = 'adjoint_memory.png'
COST_PLOT = 'adjoint_cost.png'
MEMORY_KINDS = ('reversible', 'stored')


def plot(results, figures):
    _plot_memory(results['memory'], figures)
    _plot_cost(results['cost'], figures)


def _plot_memory(memory, figures):
    plt = pyplot()
    points = memory['points']
    n = [p['steps'] for p in points]
    fig, axes = plt.subplots(1, 2, figsize=(10, 4))
    ax = axes[0]
    ax.loglog(n, [p['reversible']['traced_peak_bytes'] / 2**20
                  for p in points], 'o-', color='C0',
              label='ReversibleVerlet: run + backpropagate')
    ax.loglog(n, [p['stored']['traced_peak_bytes'] / 2**20 for p in points],
              's-', color='C3', label='stored trajectory: run + adjoint')
    ax.loglog(n, [p['stored']['stored_bytes'] / 2**20 for p in points], ':',
              color='C3', label='  of which array data stored')
    ax.set_xlabel('steps N')
    ax.set_ylabel('tracemalloc peak (MiB)')
    ax.grid(True, which='major', alpha=0.3)
    ax.legend(loc='upper left', fontsize=8)
    ax = axes[1]
    for kind, label, marker, color in (
            ('reversible', 'ReversibleVerlet', 'o-', 'C0'),
            ('stored', 'stored trajectory', 's-', 'C3')):
        ax.semilogx(n, [p[kind]['max_rss_bytes'] / 2**20 for p in points],
                    marker, color=color, label=f'{label}: peak')
        ax.semilogx(n, [p[kind]['max_rss_before_bytes'] / 2**20
                        for p in points], marker[0] + ':', color=color,
                    alpha=0.5, label=f'{label}: before the run')
    ax.set_xlabel('steps N')
    ax.set_ylabel('peak resident set size (MiB)')
    ax.grid(True, which='major', alpha=0.3)
    ax.legend(loc='upper left', fontsize=8)
    s = memory['system']
    fig.suptitle(f"{s['cluster']}, {s['temperature_K']:g} K, "
                 f"{s['timestep_fs']:g} fs: memory of a gradient through "
                 'N steps (one process per point)')
    fig.tight_layout()
    fig.savefig(figures / MEMORY_PLOT, dpi=110)
    plt.close(fig)


def _plot_cost(cost, figures):
    plt = pyplot()
    cases = cost['cases']
    labels = [case_name(c) for c in cases]
    ratio = np.array([c['backward_over_forward'] for c in cases])
    share = np.array([c['backward_share_in_products'] for c in cases])
    y = np.arange(len(cases))[::-1]
    fig, ax = plt.subplots(figsize=(9, 0.5 * len(cases) + 1.8))
    ax.barh(y, ratio * (1 - share), color='C0',
            label='retrace and adjoint bookkeeping')
    ax.barh(y, ratio * share, left=ratio * (1 - share), color='C1',
            label='Hessian-vector products')
    for yi, r in zip(y, ratio):
        ax.annotate(f'{r:.2f}', (r, yi), xytext=(3, 0),
                    textcoords='offset points', va='center', fontsize=8)
    ax.axvline(1, color='grey', lw=0.5)
    ax.set_yticks(y)
    ax.set_yticklabels(labels, fontsize=8)
    ax.set_xlabel('backpropagate time per step, in forward steps')
    ax.legend(loc='upper center', bbox_to_anchor=(0.5, -0.16), ncol=2,
              fontsize=8, frameon=False)
    ax.set_xlim(0, ratio.max() * 1.15)
    fig.tight_layout()
    fig.savefig(figures / COST_PLOT, dpi=110)
    plt.close(fig)


# -- render -------------------------------------------------------------------

def case_name(case):
    extra = [f"{case['scheme']} scheme"]
    if case['order'] != 2:
        extra.append(f"order {case['order']}")
    return f"{case['label']} ({', '.join(extra)})"


def _mib(b):
    return f'{b / 2**20:.3g}'


def _kib(b):
    return f'{b / 2**10:.4g}'


def memory_table(points):
    rows = []
    for p in points:
        ours, st = p['reversible'], p['stored']
        rows.append([
            f"{p['steps']:,}",
            _kib(ours['traced_peak_bytes']),
            f"{_mib(ours['max_rss_bytes'])} "
            f"(+{_mib(ours['max_rss_bytes'] - ours['max_rss_before_bytes'])})",
            str(ours['exact_return']),
            _kib(st['traced_peak_bytes']), _kib(st['stored_bytes']),
            f"{_mib(st['max_rss_bytes'])} "
            f"(+{_mib(st['max_rss_bytes'] - st['max_rss_before_bytes'])})",
            _kib(st['tracemalloc_own_bytes']),
            'bitwise' if p['gradients_bitwise_equal']
            else f"{p['gradient_max_relative_difference']:.2g}",
        ])
    return markdown_table(
        ['N', 'reversible: traced peak (KiB)',
         'reversible: peak RSS (MiB, + growth)', 'reversible: back at start',
         'stored: traced peak (KiB)', 'stored: array data (KiB)',
         'stored: peak RSS (MiB, + growth)',
         "stored: tracemalloc's own (KiB)",
         'gradients equal (else max rel. difference)'], rows)


def memory_observations(memory):
    points = memory['points']
    last = points[-1]
    ours = [p['reversible']['traced_peak_bytes'] for p in points]
    stored = [p['stored']['traced_peak_bytes'] for p in points]
    n = [p['steps'] for p in points]
    # Bytes per step of the stored trajectory, from the two longest runs.
    slope = (stored[-1] - stored[-2]) / (n[-1] - n[-2])
    payload = last['stored']['stored_bytes'] / last['stored']['frames']
    rss = [p[kind]['max_rss_bytes'] - p[kind]['max_rss_before_bytes']
           for p in (last,) for kind in MEMORY_KINDS]
    lines = [
        f"- ReversibleVerlet's traced peak went from {_kib(ours[0])} KiB at "
        f"N = {n[0]:,} to {_kib(ours[-1])} KiB at N = {n[-1]:,} (x"
        f"{ours[-1] / ours[0]:.3g} for x{n[-1] / n[0]:.3g} the steps). At "
        f"N = {n[-1]:,} the process's peak RSS grew by {_mib(rss[0])} MiB "
        f"during the run and gradient ({_mib(rss[1])} MiB for the stored "
        'trajectory).',
        f"- The stored trajectory's traced peak grew by {slope:.4g} bytes per "
        f"step between the two longest runs (array data: {payload:.4g} bytes "
        f"per step), to {stored[-1] / ours[-1]:.3g} times ReversibleVerlet's "
        f"at N = {n[-1]:,}.",
    ]
    if slope > 0:
        crossover = ours[-1] / slope
        lines.append(f"- At that rate the stored trajectory alone passes "
                     f"ReversibleVerlet's whole traced peak after about "
                     f"{crossover:,.0f} steps.")
    exact = all(p['reversible']['exact_return'] for p in points)
    lines.append(f"- backpropagate left the atoms bitwise at the start at "
                 f"every N: {exact}.")
    equal = [p['steps'] for p in points if p['gradients_bitwise_equal']]
    if len(equal) == len(points):
        lines.append('- The gradients of the two adjoints were bitwise '
                     'equal at every N: the retrace took every '
                     'Hessian-vector product at exactly the stored '
                     'positions.')
    else:
        worst = max(p['gradient_max_relative_difference'] for p in points)
        lines.append(f"- The gradients of the two adjoints were bitwise equal "
                     f"at N = {', '.join(f'{s:,}' for s in equal) or 'none'};"
                     f" largest relative difference {worst:.2g}.")
    moved = max(p['reversible']['centre_of_mass_moved'] for p in points)
    lines.append('- Largest gradient component: '
                 + ', '.join(f"{p['gradient_max_abs']:.3g} (N = "
                             f"{p['steps']:,})" for p in points)
                 + f'. The centre of mass had moved by at most {moved:.2g} Å '
                 'at the turning point.')
    return '\n'.join(lines)


def cost_table(cases):
    rows = []
    for c in cases:
        ps = c['per_step']
        rows.append([
            case_name(c), c['hvp_class'], c['atoms'], c['steps_per_block'],
            f"{ps['forward_force_calls']:.3g}",
            f"{ps['backward_force_calls_retrace']:.3g}",
            f"{ps['backward_products']:.3g}",
            f"{ps['backward_force_calls_in_products']:.3g}",
            f"{c['forward_ms_per_step']:.3g}",
            f"{c['backward_ms_per_step']:.3g}",
            f"**{c['backward_over_forward']:.2f}**",
            f"{c['backward_share_in_products']:.0%}",
            f"{c['product_over_force_call_time']:.2g}",
            f"{c['spread']:.0%}", f"{c['wall_over_cpu']:.2f}",
            str(c['exact_return_every_round']),
        ])
    return markdown_table(
        ['case', 'Hessian-vector product', 'atoms', 'N',
         'forward: force calls / step', 'backward: retrace force calls / step',
         'backward: products / step',
         'backward: force calls in products / step',
         'forward ms / step', 'backward ms / step',
         'backward / forward (forward steps per step)',
         'backward time in products', 'one product in force calls (time)',
         'round spread', 'wall / CPU', 'back at start every round'], rows)


def cost_observations(cases):
    lines = []
    for c in cases:
        ps, n = c['per_step'], c['steps_per_block']
        backward_calls = (ps['backward_force_calls_retrace']
                          + ps['backward_force_calls_in_products'])
        products = sorted(set(c['products_per_block']))
        line = (f"- {case_name(c)}: per step, forward "
                f"{ps['forward_force_calls']:.3g} force calls; backward "
                f"{backward_calls:.3g} force calls (retrace "
                f"{ps['backward_force_calls_retrace']:.3g}, in products "
                f"{ps['backward_force_calls_in_products']:.3g}) and "
                f"{ps['backward_products']:.3g} products "
                f"({' or '.join(map(str, products))} for {n} steps). A "
                f"backward step took {c['backward_over_forward']:.2f} "
                "forward steps' time.")
        if c['force_purity'] == 'guarded':
            line += (f" Guarded purity: "
                     f"{ps['forward_clean_recomputations']:.3g} clean "
                     f"recomputations per step forward, "
                     f"{ps['backward_clean_recomputations']:.3g} backward "
                     '(included in the force calls).')
        if ps['forward_energy_only_calls'] or ps['backward_energy_only_calls']:
            line += (f" Energy-only calls (the energy check) per step: "
                     f"{ps['forward_energy_only_calls']:.3g} forward, "
                     f"{ps['backward_energy_only_calls']:.3g} backward.")
        lines.append(line)
    return '\n'.join(lines)


SPEC = Spec(
    'Gradients by the reversible adjoint',
    blocks={'memory': block(memory_table, 'memory', 'points'),
            'memory-observations': block(memory_observations, 'memory'),
            'systems': block(lambda systems: '\n'.join(
                f'- {v}' for v in systems.values()), 'cost_systems'),
            'cost': block(cost_table, 'cost', 'cases'),
            'cost-observations': block(cost_observations, 'cost', 'cases')},
    plots=(plot,))
