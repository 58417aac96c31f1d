"""Cost per step (benchmarks/step_cost.py)."""

from __future__ import annotations

from . import Spec, figure, markdown_table, table

PLOT = 'step_cost.png'


# -- derived numbers -------------------------------------------------------

def ratio(r, name, reference='vv', clock='median_seconds'):
    med = r[clock]
    return med[name] / med[reference]


def paired_ratios(r, name, reference='vv'):
    """Per-round ratios: both blocks of a round ran close together."""
    wall = r['per_step_seconds']
    return [a / b for a, b in zip(wall[name], wall[reference])]


def overhead_percent(r, name, floor='replay', clock='median_seconds'):
    """Time beyond the floor, in % of the floor."""
    med = r[clock]
    return 100 * (med[name] - med[floor]) / med[floor]


def wall_over_cpu(r):
    """Largest wall/CPU ratio of a case's medians: 1.00 on a quiet machine."""
    return max(r['median_seconds'][k] / r['median_cpu_seconds'][k]
               for k in r['median_seconds'])


def position_extra_calls(r):
    """Extra cost of 'position' over 'velocity', in nudge force calls."""
    med = r['median_seconds']
    return (med['rv_position'] - med['rv_velocity']) / med['force']


def by_calculator(results):
    groups = {}
    for r in results:
        groups.setdefault(r['calculator'], []).append(r)
    return {k: sorted(v, key=lambda r: r['n_atoms'])
            for k, v in groups.items()}


def overhead_ratio(r, name):
    """A contestant's overhead over VelocityVerlet's."""
    return r['overhead_seconds'][name] / r['overhead_seconds']['vv']


# -- plot ------------------------------------------------------------------

#: The goals the plot draws as lines (docs/benchmarks.md states them).
TARGET_RATIO_TO_VV = 1.0
TARGET_OVERHEAD_PERCENT = 3.0
TARGET_OVERHEAD_CALCULATOR = 'asap3 EMT'
TARGET_OVERHEAD_MIN_ATOMS = 4000


def plot(results, figures):
    steps = results['step_cost']
    with figure(figures / PLOT, 2, (11, 4.3)) as (plt, fig, (left, right)):
        from matplotlib.lines import Line2D
        from matplotlib.ticker import FuncFormatter, NullFormatter
        colours = plt.rcParams['axes.prop_cycle'].by_key()['color']
        sizes = sorted({r['n_atoms'] for r in steps})
        for colour, (label, rs) in zip(colours, by_calculator(steps).items()):
            n = [r['n_atoms'] for r in rs]
            left.plot(n, [ratio(r, 'rv_velocity') for r in rs], 'o-',
                      color=colour, label=label)
            right.plot(n, [overhead_percent(r, 'rv_velocity') for r in rs],
                       'o-', color=colour)
            right.plot(n, [overhead_percent(r, 'vv') for r in rs], 'x--',
                       color=colour, alpha=0.7)
        left.axhline(TARGET_RATIO_TO_VV, color='k', lw=0.8, ls=':',
                     label=f'target: ≤ {TARGET_RATIO_TO_VV:g}')
        left.set_ylabel('Reversible (velocity) / VelocityVerlet, per step')
        left.set_title('Time per step relative to VelocityVerlet')
        right.axhline(TARGET_OVERHEAD_PERCENT, color='k', lw=0.8, ls=':')
        right.axhline(0, color='grey', lw=0.5)
        # Overheads span from a few % (noise around 0) to a few hundred %.
        right.set_yscale('symlog', linthresh=10)
        right.margins(y=0.08)
        low, high = right.get_ylim()
        right.set_yticks([t for t in (-200, -100, -50, -20, -10, -5, 0, 5, 10,
                                      20, 50, 100, 200, 500, 1000)
                          if low <= t <= high])
        right.yaxis.set_major_formatter(FuncFormatter(lambda v, _: f'{v:g}'))
        right.set_ylabel('time beyond the replay floor, % of the floor')
        right.set_title('Overhead beyond the force calls of real MD')
        right.legend(loc='best', handles=[
            Line2D([], [], color='k', marker='o', label='Reversible (velocity)'),
            Line2D([], [], color='k', marker='x', ls='--', alpha=0.7,
                   label='VelocityVerlet'),
            Line2D([], [], color='k', lw=0.8, ls=':',
                   label=f'target ({TARGET_OVERHEAD_CALCULATOR}, '
                         f'N ≥ {TARGET_OVERHEAD_MIN_ATOMS}): '
                         f'< {TARGET_OVERHEAD_PERCENT:g}%')], fontsize=8)
        left.legend(fontsize=8)
        for ax in (left, right):
            ax.set_xscale('log')
            ax.set_xticks(sizes)
            ax.xaxis.set_major_formatter(FuncFormatter(lambda v, _: f'{v:g}'))
            ax.xaxis.set_minor_formatter(NullFormatter())
            ax.set_xlabel('number of atoms')
            ax.grid(True, which='major', alpha=0.3)


# -- Markdown --------------------------------------------------------------

def ms(seconds):
    """Milliseconds with three significant digits, no exponent."""
    v = seconds * 1e3
    for limit, decimals in ((100, 0), (10, 1), (1, 2)):
        if abs(v) >= limit:
            return f'{v:.{decimals}f}'
    return f'{v:.3f}'


def with_ratio(r, name):
    return f"{ms(r['median_seconds'][name])} (×{ratio(r, name):.2f})"


def clean_fraction(r, name):
    entry = r['clean_recomputations'].get(name)
    if entry is None or r['force_purity'][name]['mode'] != 'guarded':
        return '—'
    k, n = entry['recomputations'], entry['force_calls']
    return f'{100 * k / n:.2g}% ({k}/{n})'


def us(seconds):
    """Microseconds, one decimal."""
    return f'{seconds * 1e6:.1f}'


def ms_cell(name):
    return lambda r: ms(r['median_seconds'][name])


#: The last two columns of the timing tables: how far to trust them.
NOISE_COLUMNS = (
    ('round spread', lambda r: f"{100 * max(r['spread'].values()):.0f}%"),
    ('wall / CPU', lambda r: f'{wall_over_cpu(r):.2f}'))

OVERHEAD_COLUMNS = (
    ('system', '{system}'), ('N', '{n_atoms}'),
    ('steps × rounds', '{steps_per_block} × {rounds}'),
    ('force call (µs)', lambda r: us(r['median_seconds']['force'])),
    ('VelocityVerlet overhead (µs)',
     lambda r: us(r['overhead_seconds']['vv'])),
    *((f'Reversible {name} overhead (µs, ×VV)',
       lambda r, n=f'rv_{name}': f"{us(r['overhead_seconds'][n])} "
                                 f'(×{overhead_ratio(r, n):.2f})')
      for name in ('velocity', 'position')),
    *NOISE_COLUMNS)

TIME_COLUMNS = (
    ('calculator', '{calculator}'), ('N', '{n_atoms}'),
    ('steps × rounds', '{steps_per_block} × {rounds}'),
    ('purity (auto)', lambda r: r['force_purity']['rv_velocity']['mode']),
    ('nudge floor (ms)', ms_cell('force')),
    ('replay floor (ms)', ms_cell('replay')),
    ('VelocityVerlet (ms/step)', ms_cell('vv')),
    *((f'Reversible {name} (ms/step, ×VV)',
       lambda r, n=f'rv_{name}': with_ratio(r, n))
      for name in ('velocity', 'position', 'trust')),
    ('VelocityVerlet twin (×VV)', lambda r: f"×{ratio(r, 'vv_twin'):.3f}"),
    ('clean recomputations, velocity / position',
     lambda r: f"{clean_fraction(r, 'rv_velocity')} / "
               f"{clean_fraction(r, 'rv_position')}"),
    *NOISE_COLUMNS)


LOGGING_COLUMNS = (
    ('calculator', '{calculator}'), ('N', '{n_atoms}'),
    ('nudge floor (ms)', ms_cell('force')),
    ('VelocityVerlet + logger (ms/step)', ms_cell('vv')),
    *((f'Reversible {name} + logger (ms/step, ×VV)',
       lambda r, n=f'rv_{name}': with_ratio(r, n))
      for name in ('velocity', 'position')),
    ('position − velocity (ms/step, in nudge force calls)',
     lambda r: f"{ms(r['median_seconds']['rv_position'] - r['median_seconds']['rv_velocity'])} "
               f'({position_extra_calls(r):.2f})'),
    *NOISE_COLUMNS)


def cached(key):
    """A cached query's time, also in nudge force calls."""
    return lambda r: (f'{ms(r[key])} '
                      f"({r[key] / r['median_seconds']['force']:.2f})")


CACHE_COLUMNS = (
    ('calculator', '{calculator}'), ('N', '{n_atoms}'),
    ('nudge floor (ms)', ms_cell('force')),
    ('get_forces() again (ms, in force calls)',
     cached('get_forces_again_seconds')),
    ('get_potential_energy() after get_forces() (ms, in force calls)',
     cached('energy_after_forces_seconds')))


def checks_row(r):
    """The per-step checks: 'rv_observed' (an observer attached, so the
    checks run before every step) against 'rv_unwatched' (bypassed)."""
    med = r['median_seconds']
    on, off = med['rv_observed'], med['rv_unwatched']
    paired = paired_ratios(r, 'rv_observed', 'rv_unwatched')
    diff = 1e6 * (on - off)
    watch = r['watch_changes_seconds']
    spread = max(r['spread']['rv_observed'], r['spread']['rv_unwatched'])
    return (r['calculator'], r['n_atoms'], ms(on), ms(off),
            f"×{on / off:.3f} (×{min(paired):.2f} to ×{max(paired):.2f})",
            f'{diff:+.1f}' if abs(diff) < 100 else f'{diff:+.0f}',
            f'{1e6 * watch:.2f} ({100 * watch / on:.2g}%)',
            f"{1e6 * r['watch_changes_loop_seconds']:.2f}",
            f'{100 * spread:.0f}%')


SPEC = Spec(
    'Cost per step',
    blocks={'overhead': lambda stored: table(
                OVERHEAD_COLUMNS, stored['results']['overhead']),
            'time': lambda stored: table(
                TIME_COLUMNS, stored['results']['step_cost']),
            'checks': lambda stored: markdown_table(
                ('calculator', 'N', 'Reversible velocity, observed (ms/step)',
                 'checks bypassed (ms/step)',
                 'with / without checks (per-round range)',
                 'difference of medians (µs/step)',
                 'changes() in the steps (µs/call, % of step)',
                 'changes() in a tight loop (µs/call)', 'round spread'),
                map(checks_row, stored['results']['step_cost'])),
            'logging': lambda stored: table(
                LOGGING_COLUMNS, stored['results']['logging']),
            'cache': lambda stored: table(
                CACHE_COLUMNS, stored['results']['step_cost'])},
    plots=(plot,))
