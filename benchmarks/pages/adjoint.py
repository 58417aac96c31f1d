"""Gradients by the reversible adjoint (benchmarks/adjoint.py)."""

from __future__ import annotations

from . import Spec, block, figure, table

MEMORY_PLOT = 'adjoint_memory.png'


def plot(results, figures):
    memory = results['memory']
    with figure(figures / MEMORY_PLOT, 1, (6, 4)) as (plt, fig, ax):
        points = memory['points']
        n = [p['steps'] for p in points]
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
        s = memory['system']
        ax.set_title(f"{s['cluster']}, {s['temperature_K']:g} K, "
                     f"{s['timestep_fs']:g} fs: memory of a gradient through "
                     'N steps', fontsize=9)


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


def rss(run):
    """Peak RSS in MiB, with its growth during the run."""
    return (f"{_mib(run['max_rss_bytes'])} "
            f"(+{_mib(run['max_rss_bytes'] - run['max_rss_before_bytes'])})")


MEMORY_COLUMNS = (
    ('N', '{steps:,}'),
    ('reversible: traced peak (KiB)',
     lambda p: _kib(p['reversible']['traced_peak_bytes'])),
    ('reversible: peak RSS (MiB, + growth)', lambda p: rss(p['reversible'])),
    ('reversible: back at start', '{reversible[exact_return]}'),
    ('stored: traced peak (KiB)',
     lambda p: _kib(p['stored']['traced_peak_bytes'])),
    ('stored: array data (KiB)', lambda p: _kib(p['stored']['stored_bytes'])),
    ('stored: peak RSS (MiB, + growth)', lambda p: rss(p['stored'])),
    ("stored: tracemalloc's own (KiB)",
     lambda p: _kib(p['stored']['tracemalloc_own_bytes'])),
    ('gradients equal (else max rel. difference)',
     lambda p: 'bitwise' if p['gradients_bitwise_equal']
     else f"{p['gradient_max_relative_difference']:.2g}"))

COST_COLUMNS = (
    ('case', case_name), ('Hessian-vector product', '{hvp_class}'),
    ('atoms', '{atoms}'), ('N', '{steps_per_block}'),
    ('forward: force calls / step', '{per_step[forward_force_calls]:.3g}'),
    ('backward: retrace force calls / step',
     '{per_step[backward_force_calls_retrace]:.3g}'),
    ('backward: products / step', '{per_step[backward_products]:.3g}'),
    ('backward: force calls in products / step',
     '{per_step[backward_force_calls_in_products]:.3g}'),
    ('forward ms / step', '{forward_ms_per_step:.3g}'),
    ('backward ms / step', '{backward_ms_per_step:.3g}'),
    ('backward / forward (forward steps per step)',
     '**{backward_over_forward:.2f}**'),
    ('backward time in products', '{backward_share_in_products:.0%}'),
    ('one product in force calls (time)',
     '{product_over_force_call_time:.2g}'),
    ('round spread', '{spread:.0%}'), ('wall / CPU', '{wall_over_cpu:.2f}'),
    ('back at start every round', '{exact_return_every_round}'))

def memory_values(results):
    """The prose's numbers: growth of the traced peaks over the points."""
    points = results['memory']['points']
    first, last = points[0], points[-1]
    ours = [p['reversible']['traced_peak_bytes'] for p in points]
    stored = [p['stored']['traced_peak_bytes'] for p in points]
    # Bytes per step of the stored trajectory, from the two longest runs.
    slope = (stored[-1] - stored[-2]) / (last['steps'] - points[-2]['steps'])
    equal = [p['steps'] for p in points if p['gradients_bitwise_equal']]
    return {
        'first_kib': _kib(ours[0]), 'last_kib': _kib(ours[-1]),
        'first_n': first['steps'], 'last_n': last['steps'],
        'peak_growth': ours[-1] / ours[0],
        'steps_growth': last['steps'] / first['steps'],
        'rss_ours': _mib(last['reversible']['max_rss_bytes']
                         - last['reversible']['max_rss_before_bytes']),
        'rss_stored': _mib(last['stored']['max_rss_bytes']
                           - last['stored']['max_rss_before_bytes']),
        'slope': slope,
        'payload': last['stored']['stored_bytes'] / last['stored']['frames'],
        'stored_over_ours': stored[-1] / ours[-1],
        'crossover': ours[-1] / slope if slope > 0 else float('nan'),
        'all_exact': all(p['reversible']['exact_return'] for p in points),
        'gradients_equal_at': ', '.join(f'{n:,}' for n in equal) or 'none',
        'largest_gradients': ', '.join(
            f"{p['gradient_max_abs']:.3g} (N = {p['steps']:,})"
            for p in points),
        'moved': max(p['reversible']['centre_of_mass_moved']
                     for p in points)}


SPEC = Spec(
    'Gradients by the reversible adjoint',
    blocks={'memory': lambda stored: table(
                MEMORY_COLUMNS, stored['results']['memory']['points']),
            'systems': block(lambda systems: '\n'.join(
                f'- {v}' for v in systems.values()), 'cost_systems'),
            'cost': lambda stored: table(COST_COLUMNS,
                                         stored['results']['cost']['cases'])},
    plots=(plot,), values=memory_values)
