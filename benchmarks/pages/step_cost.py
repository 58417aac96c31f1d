"""Cost per step: ReversibleVerlet against VelocityVerlet and the force call.

Measured by benchmarks/step_cost.py; the method is described there and in
the rendered text below.
"""

from __future__ import annotations

from . import markdown_table, pyplot

TITLE = 'Cost per step'
PLOT = 'step_cost.png'
OVERHEAD_PLOT = 'step_cost_overhead.png'

#: The targets set for the integrator, judged on every run's numbers.
TARGET_RATIO_TO_VV = 1.0
TARGET_OVERHEAD_PERCENT = 3.0
TARGET_OVERHEAD_CALCULATOR = 'asap3 EMT'
TARGET_OVERHEAD_MIN_ATOMS = 4000
#: Reversible velocity counts as "slower than VelocityVerlet" above this ratio.
SLOWER_THRESHOLD = 1.05
#: Target of the overhead cases: ReversibleVerlet's time beyond the force
#: call at most VelocityVerlet's, at every size.
TARGET_OVERHEAD_RATIO = 1.0
#: The energy check (its trigger and measurements) per step, % of a step.
TARGET_CHECK_PERCENT = 1.0

# -- derived numbers -------------------------------------------------------

#: The process's CPU time: single-threaded here, so on a machine shared with
#: other jobs it is the step's cost without the waits for a core.
CPU = 'median_cpu_seconds'


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


def in_force_calls(r, key):
    return r[key] / r['median_seconds']['force']


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


def overhead_ratio(r, name, key='overhead_seconds'):
    """A contestant's overhead over VelocityVerlet's."""
    return r[key][name] / r[key]['vv']


def paired_overhead_ratios(r, name):
    """Per-round overhead ratios, each round's floor subtracted."""
    wall = r['per_step_seconds']
    return [(a - f) / (b - f) for a, b, f in
            zip(wall[name], wall['vv'], wall['force'])]


# -- plot ------------------------------------------------------------------

def plot(results, figures):
    if results.get('overhead'):
        plot_overhead(results['overhead'], figures)
    steps = results['step_cost']
    plt = pyplot()
    from matplotlib.lines import Line2D
    from matplotlib.ticker import FuncFormatter, NullFormatter
    fig, (left, right) = plt.subplots(1, 2, figsize=(11, 4.3))
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
    fig.tight_layout()
    fig.savefig(figures / PLOT, dpi=110)
    plt.close(fig)


def plot_overhead(overheads, figures):
    plt = pyplot()
    from matplotlib.ticker import FuncFormatter, NullFormatter
    fig, ax = plt.subplots(figsize=(6.5, 4.3))
    n = [r['n_atoms'] for r in overheads]
    for name, label, style in (('vv', 'VelocityVerlet', 'x--'),
                               ('rv_velocity', 'Reversible velocity', 'o-'),
                               ('rv_position', 'Reversible position', 's:')):
        ax.plot(n, [1e6 * r['overhead_seconds'][name] for r in overheads],
                style, label=label)
    ax.plot(n, [1e6 * r['median_seconds']['force'] for r in overheads],
            'k.-', lw=0.8, alpha=0.6, label='the force call (floor)')
    ax.set_xscale('log')
    ax.set_yscale('log')
    ax.set_xticks(n)
    ax.xaxis.set_major_formatter(FuncFormatter(lambda v, _: f'{v:g}'))
    ax.xaxis.set_minor_formatter(NullFormatter())
    ax.set_xlabel('number of atoms')
    ax.set_ylabel('µs per step beyond the force call')
    ax.set_title('Integrator overhead (CachedForces calculator)')
    ax.grid(True, which='major', alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(figures / OVERHEAD_PLOT, dpi=110)
    plt.close(fig)


# -- Markdown --------------------------------------------------------------

def ms(seconds):
    """Milliseconds with three significant digits, no exponent."""
    v = seconds * 1e3
    for limit, decimals in ((100, 0), (10, 1), (1, 2)):
        if abs(v) >= limit:
            return f'{v:.{decimals}f}'
    return f'{v:.3f}'


def twin_gap(r):
    """|VelocityVerlet twin / VelocityVerlet - 1|: how far two identical
    contestants came apart; None in results from before the twin."""
    if 'vv_twin' not in r['median_seconds']:
        return None
    return abs(ratio(r, 'vv_twin') - 1)


def twin_cell(r):
    return '–' if twin_gap(r) is None else f"×{ratio(r, 'vv_twin'):.3f}"


def with_ratio(r, name):
    return f"{ms(r['median_seconds'][name])} (×{ratio(r, name):.2f})"


def beyond(r, name, floor):
    med = r['median_seconds']
    return (f'{ms(med[name] - med[floor])} '
            f'({overhead_percent(r, name, floor):+.0f}%)')


def clean_fraction(r, name):
    entry = r['clean_recomputations'].get(name)
    if entry is None or r['force_purity'][name]['mode'] != 'guarded':
        return '—'
    k, n = entry['recomputations'], entry['force_calls']
    return f'{100 * k / n:.2g}% ({k}/{n})'


def us(seconds):
    """Microseconds, one decimal."""
    return f'{seconds * 1e6:.1f}'


def integrator_overhead_table(results):
    header = ('system', 'N', 'steps × rounds', 'force call (µs)',
              'VelocityVerlet overhead (µs)',
              'Reversible velocity overhead (µs, ×VV)',
              'Reversible position overhead (µs, ×VV)',
              'velocity ×VV, per-round range', 'on CPU time: velocity ×VV',
              'round spread', 'wall / CPU')
    rows = []
    for r in results:
        o = r['overhead_seconds']
        paired = paired_overhead_ratios(r, 'rv_velocity')
        rows.append((
            r['system'], r['n_atoms'],
            f"{r['steps_per_block']} × {r['rounds']}",
            us(r['median_seconds']['force']), us(o['vv']),
            f"{us(o['rv_velocity'])} "
            f"(×{overhead_ratio(r, 'rv_velocity'):.2f})",
            f"{us(o['rv_position'])} "
            f"(×{overhead_ratio(r, 'rv_position'):.2f})",
            f'×{min(paired):.2f} to ×{max(paired):.2f}',
            f"×{overhead_ratio(r, 'rv_velocity', 'overhead_cpu_seconds'):.2f}",
            f"{100 * max(r['spread'].values()):.0f}%",
            f'{wall_over_cpu(r):.2f}'))
    return markdown_table(header, rows)


def verdict(target, results, missed, describe, where='in', noun='cases'):
    """One line: ``target`` met in how many of ``results``, and each
    missed one as ``describe(r)`` gives it."""
    line = (f'- {target}: met {where} {len(results) - len(missed)} of '
            f'{len(results)} {noun}')
    if missed:
        line += f'; missed {where} ' + '; '.join(map(describe, missed))
    return line + '.'


def overhead_target_lines(results):
    out = []
    for name, scheme in (('rv_velocity', 'velocity'),
                         ('rv_position', 'position')):
        def describe(r, name=name):
            o = r['overhead_seconds']
            return (f"N={r['n_atoms']}: ×{overhead_ratio(r, name):.2f} "
                    f"(+{us(o[name] - o['vv'])} µs/step)")
        missed = [r for r in results
                  if overhead_ratio(r, name) > TARGET_OVERHEAD_RATIO]
        out.append(verdict(f"Reversible '{scheme}' overhead ≤ "
                           "VelocityVerlet's", results, missed, describe,
                           where='at', noun='sizes'))
    return '\n'.join(out)


def overhead_section(results, settings):
    if not results:
        return ''
    return f"""\
### The integrators' own overhead

Time per step beyond the force call, with a calculator whose force call
costs a few microseconds (`CachedForces` in `benchmarks/systems.py`: zero
forces returned for any positions, behind a cache that checks only whether
the positions changed, as asap3's does), so that what is left is the
integrator's own Python and numpy work. Free argon icosahedra up to 561
atoms, then periodic fcc argon; every contestant on its own copy of the
atoms with its own calculator, {settings['rounds']} interleaved rounds of
blocks of about {settings['block_seconds']:g} s (VelocityVerlet), order
rotating. Overhead = median step time − median time of the force call
alone (the nudge floor: one coordinate moved, then `get_forces`), in the
same rounds. ReversibleVerlet runs with `force_purity='auto'`, which takes
the calculator as pure (`forces_are_pure = True`); its overhead includes
the checks for changes made between steps, the restart record, and the
energy check. VelocityVerlet's includes the two cached `get_forces` calls
that its step and ASE's loop make besides the one that computes. The
per-round range gives each round's ratio with that round's floor
subtracted.

![Overhead per step against the number of atoms](benchmarks/{OVERHEAD_PLOT})

{integrator_overhead_table(results)}

{overhead_target_lines(results)}

"""


def case_label(r):
    return f"{r['calculator']}, N={r['n_atoms']}"


def step_cost_table(results):
    header = ('calculator', 'N', 'steps × rounds', 'purity (auto)',
              'nudge floor (ms)', 'replay floor (ms)',
              'VelocityVerlet (ms/step)',
              'Reversible velocity (ms/step, ×VV)',
              'Reversible position (ms/step, ×VV)',
              'Reversible trust (ms/step, ×VV)',
              'VelocityVerlet twin (×VV)')
    rows = [(r['calculator'], r['n_atoms'],
             f"{r['steps_per_block']} × {r['rounds']}",
             r['force_purity']['rv_velocity']['mode'],
             ms(r['median_seconds']['force']),
             ms(r['median_seconds']['replay']),
             ms(r['median_seconds']['vv']),
             with_ratio(r, 'rv_velocity'), with_ratio(r, 'rv_position'),
             with_ratio(r, 'rv_trust'), twin_cell(r))
            for r in results]
    return markdown_table(header, rows)


def overhead_table(results):
    header = ('calculator', 'N', 'replay − nudge floor (ms, %)',
              'VV beyond replay floor (ms, %)',
              'Reversible velocity beyond replay floor (ms, %)',
              'Reversible velocity beyond nudge floor (ms, %)',
              'clean recomputations, velocity / position',
              'round spread', 'wall / CPU')
    rows = [(r['calculator'], r['n_atoms'],
             beyond(r, 'replay', 'force'),
             beyond(r, 'vv', 'replay'),
             beyond(r, 'rv_velocity', 'replay'),
             beyond(r, 'rv_velocity', 'force'),
             f"{clean_fraction(r, 'rv_velocity')} / "
             f"{clean_fraction(r, 'rv_position')}",
             f"{100 * max(r['spread'].values()):.0f}%",
             f'{wall_over_cpu(r):.2f}')
            for r in results]
    return markdown_table(header, rows)


def logging_table(results):
    header = ('calculator', 'N', 'nudge floor (ms)',
              'VelocityVerlet + logger (ms/step)',
              'Reversible velocity + logger (ms/step, ×VV)',
              'Reversible position + logger (ms/step, ×VV)',
              'position − velocity (ms/step, in nudge force calls)',
              'round spread', 'wall / CPU')
    rows = []
    for r in results:
        med = r['median_seconds']
        rows.append((r['calculator'], r['n_atoms'], ms(med['force']),
                     ms(med['vv']), with_ratio(r, 'rv_velocity'),
                     with_ratio(r, 'rv_position'),
                     f"{ms(med['rv_position'] - med['rv_velocity'])} "
                     f'({position_extra_calls(r):.2f})',
                     f"{100 * max(r['spread'].values()):.0f}%",
                     f'{wall_over_cpu(r):.2f}'))
    return markdown_table(header, rows)


def checked(r):
    """The contestant whose steps run the checks: 'rv_observed' (an
    observer attached); 'rv_velocity' in results from before a plain run()
    left the checks out between its steps."""
    return 'rv_observed' if 'rv_observed' in r['median_seconds'] \
        else 'rv_velocity'


def checks_table(results):
    header = ('calculator', 'N', 'Reversible velocity, observed (ms/step)',
              'checks bypassed (ms/step)',
              'with / without checks (per-round range)',
              'difference of medians (µs/step)',
              'changes() in the steps (µs/call, % of step)',
              'changes() in a tight loop (µs/call)', 'round spread')
    rows = []
    for r in results:
        med = r['median_seconds']
        paired = paired_ratios(r, checked(r), 'rv_unwatched')
        diff = 1e6 * (med[checked(r)] - med['rv_unwatched'])
        watch = r['watch_changes_seconds']
        spread = max(r['spread'][k] for k in (checked(r), 'rv_unwatched'))
        rows.append((r['calculator'], r['n_atoms'], ms(med[checked(r)]),
                     ms(med['rv_unwatched']),
                     f"×{ratio(r, checked(r), 'rv_unwatched'):.3f} "
                     f'(×{min(paired):.2f} to ×{max(paired):.2f})',
                     f'{diff:+.1f}' if abs(diff) < 100 else f'{diff:+.0f}',
                     f'{1e6 * watch:.2f} '
                     f"({100 * watch / med[checked(r)]:.2g}%)",
                     f"{1e6 * r['watch_changes_loop_seconds']:.2f}",
                     f'{100 * spread:.0f}%'))
    return markdown_table(header, rows)


def check_share(r):
    """The energy check's time per step in % of a Reversible velocity step
    (the median step of the rounds, which includes it)."""
    return (100 * r['energy_check_seconds_per_step']
            / r['median_seconds']['rv_velocity'])


def energy_check_table(results):
    header = ('case', 'N', 'energy check (µs/step, % of step)',
              'median call (µs)', 'energy measurements / steps')
    rows = [(r.get('calculator', r.get('system')), r['n_atoms'],
             f"{us(r['energy_check_seconds_per_step'])} "
             f'({check_share(r):.2g}%)',
             f"{1e6 * r['energy_check_median_call_seconds']:.2f}",
             f"{r['energy_check_measurements']} / {r['energy_check_steps']}")
            for r in results if 'energy_check_seconds_per_step' in r]
    return markdown_table(header, rows)


def energy_check_lines(results):
    timed = [r for r in results if 'energy_check_seconds_per_step' in r]
    if not timed:
        return '- The energy check was not timed in this run.'
    missed = [r for r in timed if check_share(r) > TARGET_CHECK_PERCENT]

    def describe(r):
        return (f"{r.get('calculator', r.get('system'))}, N={r['n_atoms']}: "
                f'{check_share(r):.2g}% '
                f"({us(r['energy_check_seconds_per_step'])} µs of "
                f"{us(r['median_seconds']['rv_velocity'])} µs)")
    return verdict(f'Energy check ≤ {TARGET_CHECK_PERCENT:g}% of a step',
                   timed, missed, describe)


def checks_lines(results):
    """The per-step checks, alone and in the step loop."""
    def share(r):
        return r['watch_changes_seconds'] / r['median_seconds'][checked(r)]

    def with_without(r):
        return ratio(r, checked(r), 'rv_unwatched')

    alone = sorted(results, key=lambda r: r['watch_changes_seconds'])
    tight = [1e6 * r['watch_changes_loop_seconds'] for r in results]
    top = max(results, key=share)
    loop = sorted(results, key=with_without)
    unresolved = sum(min(p) <= 1 <= max(p) for p in (
        paired_ratios(r, checked(r), 'rv_unwatched') for r in results))
    return (f'- The per-step checks (`SystemWatch.changes`, timed in the '
            f"steps) cost {1e6 * alone[0]['watch_changes_seconds']:.2f} µs "
            f'({case_label(alone[0])}) to '
            f"{1e6 * alone[-1]['watch_changes_seconds']:.2f} µs "
            f'({case_label(alone[-1])}) per call, at most '
            f'{100 * share(top):.2g}% of an observed Reversible velocity step '
            f'({case_label(top)}); in a tight loop {min(tight):.2f} to '
            f'{max(tight):.2f} µs.\n'
            f'- In the step loop, observed Reversible velocity with / without the '
            f'checks ranges from ×{with_without(loop[0]):.3f} '
            f'({case_label(loop[0])}) to ×{with_without(loop[-1]):.3f} '
            f'({case_label(loop[-1])}); the per-round ratios lie on both '
            f'sides of 1 in {unresolved} of {len(results)} cases.')


def cache_table(results):
    header = ('calculator', 'N', 'nudge floor (ms)',
              'get_forces() again (ms, in force calls)',
              'get_potential_energy() after get_forces() '
              '(ms, in force calls)')
    rows = [(r['calculator'], r['n_atoms'], ms(r['median_seconds']['force']),
             *(f'{ms(r[key])} ({in_force_calls(r, key):.2f})'
               for key in ('get_forces_again_seconds',
                           'energy_after_forces_seconds')))
            for r in results]
    return markdown_table(header, rows)


def pair_section(pairs, rounds, steps):
    """Reversible velocity against VelocityVerlet with only the nudge floor
    beside them in the rounds (see benchmarks/step_cost.py)."""
    if not pairs:
        return ''
    header = ('calculator', 'N', 'steps × rounds', 'VelocityVerlet (ms/step)',
              'Reversible velocity (ms/step, ×VV)', 'per-round range',
              'on CPU time', 'same case, all contestants in the rounds')
    alongside = {(r['calculator'], r['n_atoms']): r for r in steps}
    rows = []
    for r in pairs:
        paired = paired_ratios(r, 'rv_velocity')
        same = alongside.get((r['calculator'], r['n_atoms']))
        rows.append((r['calculator'], r['n_atoms'],
                     f"{r['steps_per_block']} × {r['rounds']}",
                     ms(r['median_seconds']['vv']),
                     with_ratio(r, 'rv_velocity'),
                     f'×{min(paired):.2f} to ×{max(paired):.2f}',
                     f"×{ratio(r, 'rv_velocity', clock=CPU):.3f}",
                     f"×{ratio(same, 'rv_velocity'):.3f}" if same else '–'))
    missed = [r for r in pairs
              if ratio(r, 'rv_velocity') > TARGET_RATIO_TO_VV]
    line = verdict(
        "Reversible 'velocity' per step ≤ VelocityVerlet, measured in pairs",
        pairs, missed,
        lambda r: f"{case_label(r)}: ×{ratio(r, 'rv_velocity'):.3f}")
    return f"""
Measured again in {rounds} rounds with only the nudge floor, VelocityVerlet
and Reversible velocity in them. With all the contestants above, each block
starts with caches the others have filled; in one A/B of 21 rounds at 4000
atoms that made Reversible velocity ×1.23 of VelocityVerlet with six
contestants in the rounds and ×1.03 with three (see
`benchmarks/step_cost.py`). A user's single run is closer to this.

{markdown_table(header, rows)}

{line}
"""


def target_lines(results):
    """The cost targets, judged on this run's numbers."""
    out = []
    for name, scheme in (('rv_velocity', 'velocity'),
                         ('rv_position', 'position')):
        missed = [r for r in results
                  if ratio(r, name) > TARGET_RATIO_TO_VV]
        head = (f"- Reversible '{scheme}' (force_purity='auto') per step "
                f'≤ VelocityVerlet: met in {len(results) - len(missed)} of '
                f'{len(results)} cases')
        if not missed:
            out.append(head + '.')
            continue

        def item(r):
            paired = paired_ratios(r, name)
            med = r['median_seconds']
            consistent = ('slower in every round'
                          if min(paired) > TARGET_RATIO_TO_VV
                          else 'not slower in every round')
            gap = twin_gap(r)
            if gap is not None:
                consistent += (
                    '; within the twin control\'s '
                    f'{100 * gap:.1f}%, so not resolved'
                    if ratio(r, name) - 1 <= gap else
                    f'; beyond the twin control\'s {100 * gap:.1f}%')
            return (f'{case_label(r)}: ×{ratio(r, name):.3f} '
                    f"(+{ms(med[name] - med['vv'])} ms/step; per-round "
                    f'ratios ×{min(paired):.2f} to ×{max(paired):.2f}, '
                    f'{consistent}; on CPU time '
                    f'×{ratio(r, name, clock=CPU):.3f})')
        out.append(head + '; missed in ' + '; '.join(map(item, missed))
                   + '.')
    big = [r for r in results
           if r['calculator'] == TARGET_OVERHEAD_CALCULATOR
           and r['n_atoms'] >= TARGET_OVERHEAD_MIN_ATOMS]
    if not big:
        out.append(f'- Overhead target ({TARGET_OVERHEAD_CALCULATOR}, '
                   f'N ≥ {TARGET_OVERHEAD_MIN_ATOMS}): no such case in '
                   f'this run.')
    for r in big:
        value = overhead_percent(r, 'rv_velocity')
        verdict = 'met' if value < TARGET_OVERHEAD_PERCENT else 'missed'
        out.append(f"- Reversible 'velocity' beyond the replay floor "
                   f'< {TARGET_OVERHEAD_PERCENT:g}% ({case_label(r)}): '
                   f'{value:+.1f}%, {verdict} (on CPU time '
                   f"{overhead_percent(r, 'rv_velocity', clock=CPU):+.1f}%; "
                   f"VelocityVerlet: {overhead_percent(r, 'vv'):+.1f}%, "
                   f"on CPU time {overhead_percent(r, 'vv', clock=CPU):+.1f}%)"
                   '.')
    return '\n'.join(out)


def summary(step_results, log_results):
    """Observations computed from this run's numbers."""
    out = []
    vel = sorted(step_results, key=lambda r: ratio(r, 'rv_velocity'))
    lo, hi = vel[0], vel[-1]
    out.append(f"- Reversible velocity / VelocityVerlet ranges from "
               f"×{ratio(lo, 'rv_velocity'):.2f} ({case_label(lo)}) to "
               f"×{ratio(hi, 'rv_velocity'):.2f} ({case_label(hi)}).")
    cpu = sorted(step_results,
                 key=lambda r: ratio(r, 'rv_velocity', clock=CPU))
    out.append(f"- On CPU time the same ratio ranges from "
               f"×{ratio(cpu[0], 'rv_velocity', clock=CPU):.2f} "
               f"({case_label(cpu[0])}) to "
               f"×{ratio(cpu[-1], 'rv_velocity', clock=CPU):.2f} "
               f"({case_label(cpu[-1])}).")
    slower = [r for r in step_results
              if ratio(r, 'rv_velocity') > SLOWER_THRESHOLD]
    if slower:
        def excess(r):
            med = r['median_seconds']
            return (f"{case_label(r)}: "
                    f"+{100 * (ratio(r, 'rv_velocity') - 1):.0f}% "
                    f"(+{ms(med['rv_velocity'] - med['vv'])} ms/step)")
        out.append(f'- Reversible velocity is more than '
                   f'{100 * (SLOWER_THRESHOLD - 1):.0f}% slower than '
                   f'VelocityVerlet in: '
                   + '; '.join(map(excess, slower)) + '.')
    else:
        out.append(f'- Reversible velocity is nowhere more than '
                   f'{100 * (SLOWER_THRESHOLD - 1):.0f}% slower than '
                   f'VelocityVerlet.')
    rebuild = sorted(step_results,
                     key=lambda r: overhead_percent(r, 'replay', 'force'))
    out.append(f'- The replay floor (force calls of real MD, list rebuilds '
               f'included) exceeds the nudge floor by '
               f"{overhead_percent(rebuild[0], 'replay', 'force'):+.0f}% "
               f'({case_label(rebuild[0])}) to '
               f"{overhead_percent(rebuild[-1], 'replay', 'force'):+.0f}% "
               f'({case_label(rebuild[-1])}).')
    purity_cost = [ratio(r, 'rv_velocity', 'rv_trust') for r in step_results]
    out.append(f"- Force purity handling (auto vs 'trust', velocity scheme) "
               f"costs ×{min(purity_cost):.2f} to ×{max(purity_cost):.2f}.")
    out.append(checks_lines(step_results))
    fractions = []
    for r in step_results:
        for name in ('rv_velocity', 'rv_position'):
            entry = r['clean_recomputations'].get(name)
            if entry and r['force_purity'][name]['mode'] == 'guarded':
                fractions.append(entry['recomputations']
                                 / entry['force_calls'])
    if fractions:
        out.append(f'- Guarded (asap3) force calls needing a clean '
                   f'recomputation: {100 * min(fractions):.2g}% to '
                   f'{100 * max(fractions):.2g}% (each recomputes the '
                   f'forces from a freshly built neighbour list).')

    def recomputes(key, threshold):
        hits = [r for r in step_results
                if in_force_calls(r, key) > threshold]
        return '; '.join(f'{case_label(r)}: {in_force_calls(r, key):.2f}'
                         for r in hits)

    items = recomputes('get_forces_again_seconds', 0.5)
    if items:
        out.append(f'- get_forces() at unchanged positions recomputes '
                   f'(cost in force calls) for {items}. VelocityVerlet, which '
                   f'asks for the forces again at the start and end of '
                   f'each step, pays for that; ReversibleVerlet keeps its '
                   f'own copy of the forces and does not.')
    items = recomputes('energy_after_forces_seconds', 0.1)
    if items:
        out.append(f'- get_potential_energy() right after get_forces() '
                   f'computes the energy again (cost in force calls) for '
                   f'{items}. A logger then pays that with every '
                   f'integrator, and the logged energy at the end of a '
                   f"'position' step is no extra work.")
    for r in log_results:
        out.append(f"- With a logger every step, 'position' costs "
                   f'{position_extra_calls(r):.2f} nudge force calls per '
                   f"step more than 'velocity' ({case_label(r)}).")
    worst = max(step_results + log_results, key=wall_over_cpu)
    out.append(f'- Largest wall / CPU time ratio: {wall_over_cpu(worst):.2f} '
               f'({case_label(worst)}); well above 1 means other processes '
               f'took the CPU during the blocks and the wall times there are '
               f'noisier.')
    return '\n'.join(out)


def markdown(results):
    s = results['settings']
    steps, logging = results['step_cost'], results['logging']
    systems = '; '.join(sorted({f"{r['calculator']}: {r['system']}"
                                for r in steps}))
    return f"""\
How much a step of `ReversibleVerlet` costs against ASE's `VelocityVerlet`
and against the calculator's force call alone, for periodic crystals
({systems}) at {s['ar_temperature_K']:g} K (Ar) and \
{s['cu_temperature_K']:g} K (Cu), time step {s['timestep_fs']:g} fs.

![Reversible velocity / VelocityVerlet per step (left) and time beyond the \
replay floor in % of the floor (right), against the number of atoms]\
(benchmarks/{PLOT})

### Method

Each contestant runs on its own copy of the same thermalised atoms
(Maxwell-Boltzmann, seed 0) with its own fresh calculator. After
{s['warmup_steps']} warm-up steps each, the contestants run blocks of the
same number of steps, chosen per case so that a VelocityVerlet block takes
about {s['block_seconds']:g} s (at least {s['min_steps']} steps), in
{s['rounds']} rounds with the order rotating each round. Times are medians
over rounds of block time / steps; ratios are ratios of medians. "Round
spread" is the largest (max − min) / median over the contestants of a case:
differences smaller than that are noise. "Wall / CPU" is the largest ratio
of a contestant's median wall time to its median CPU time
(`time.process_time`, also in the JSON): near 1.00 the process had the CPU
to itself. BLAS runs on one thread so that numpy's thread hand-offs do not
add scheduler delays to the steps.

- **nudge floor**: one atom moved by {s['floor_nudge_angstrom']:g} Å, then
  `atoms.get_forces(md=True)`: a full calculation that never rebuilds the
  neighbour list.
- **replay floor**: the positions of a VelocityVerlet run of the same system
  from the same start (recorded before the rounds, fresh calculator), set
  frame by frame with `atoms.set_positions` followed by
  `atoms.get_forces(md=True)`. It includes the neighbour-list updates and
  rebuilds that MD really causes, so time beyond it is the integrator's
  own work (plus its extra force calls, if any).
- **VelocityVerlet**: `ase.md.verlet.VelocityVerlet`.
- **Reversible velocity / position**: `ReversibleVerlet(scheme=...)` with
  `force_purity='auto'` (exact reversal): 'sorted' for ASE calculators,
  'guarded' for asap3.
- **Reversible trust**: `ReversibleVerlet(scheme='velocity',
  force_purity='trust')` with its spot check switched off (it would stop
  asap3 within a few hundred steps): the cost without any purity
  handling. *Not exact* for these calculators; a baseline only.
- **VelocityVerlet twin**: a second `VelocityVerlet` on its own copy of
  the atoms with its own calculator, in the same rounds. It does exactly
  what the first does, so its ratio to it is how far two identical
  contestants come apart here (their arrays and the calculator's memory
  differ): the resolution of the case's other ratios.
- **observed / checks bypassed** (`rv_observed`, `rv_unwatched` in the
  JSON): Reversible velocity with an observer that does nothing attached,
  so that the checks for changes run before every step, and the same with
  the integrator's `SystemWatch` replaced by a stub that never reports a
  change (benchmark only): the control for those checks. See "Cost of the
  per-step checks".
- **clean recomputations**: for 'guarded', the share of force evaluations
  (one per step) whose kick was recomputed from a freshly built neighbour
  list, during the timed blocks, as count / force evaluations.

{overhead_section(results.get('overhead'), s.get('overhead'))}\
### Time per step

{step_cost_table(steps)}

### Overhead beyond the force call

Median step time minus a floor, in ms and in % of that floor.

{overhead_table(steps)}

### Cost of the per-step checks

Before every step that code outside it may have preceded (observers, a
caller of `irun`; a plain `run()` checks once, at its start)
`ReversibleVerlet` compares the calculator, its parameters, the
constraints, cell, pbc, atomic numbers and masses with a snapshot
(`SystemWatch.changes`, `ase_reversible/md/watch.py`), then the positions
and momenta. "Observed" is Reversible velocity with an observer that does
nothing, so the checks run before every step; "checks bypassed" is the
same with that comparison replaced by a stub reporting no change, timed in
the same rounds: the difference of the medians is the checks' cost in the step loop,
noise where it is within the round spread (of these two contestants) or
the per-round ratios lie on both sides of 1. The comparison is also timed
directly on the observed contestant after the rounds, with
nothing changed (the path of every step): "in the steps" is the median of
its calls (`time.perf_counter` around each) during one more block of the
same number of steps, in µs and in % of that contestant's median step;
"in a tight loop" is the median over {s['watch_blocks']} blocks of
{s['watch_calls']} back-to-back calls. The tight loop runs with warm caches
and is the lower bound; in the steps the force call has left the caches
cold, and that is what a step pays.

{checks_table(steps)}

### Cost of the energy check

The energy check (`InvariantCheck`, `ase_reversible/core/engine.py`) reads
the kinetic energy of the exact momenta every second step and measures the
total energy on its schedule or when that reading moved. It is timed on
the Reversible velocity contestant during one more block after the
rounds (`time.perf_counter` around each call, which adds about 0.1 µs):
its total time per step, in µs and in % of that contestant's median step,
and its median call, the trigger path nearly every step takes. The same
is given for the overhead cases, whose force call costs microseconds, as
the worst case.

{energy_check_table(steps + (results.get('overhead') or []))}

### Targets

Judged on the wall-time medians above; a ratio within the round spread of
1 is not resolved by this run. CPU time is given beside them: the process
is single-threaded, so where wall / CPU is well above 1 (other processes
held the CPU), CPU time is the steadier estimate of the cost.

{target_lines(steps)}
{energy_check_lines(steps)}
{pair_section(results.get('pairs'), results.get('pair_rounds'), steps)}

### Scheme cost under logging

The same measurement with an `MDLogger` (writing to an `io.StringIO`)
attached every step (no replay floor). Kick-drift-kick ('velocity') ends a
step with a force calculation at the new positions, so the logger finds the
energy in the calculator's cache (if the calculator keeps it; see the
diagnostic below); drift-kick-drift ('position') ends a step between force
calculations, so the logger's energy is a calculation of its own at every
logged step. The second to last column gives that difference in units of
the nudge floor.

{logging_table(logging)}

### Diagnostic: what the calculators cache

Asked again at unchanged positions (on the nudge-floor contestant after the
rounds; median of three blocks): `get_forces()` repeated, as VelocityVerlet
does at the start and end of each step, and `get_potential_energy()` right
after `get_forces()`, as a logger does. A cache hit costs microseconds; a
recomputation costs up to a whole force call.

{cache_table(steps)}

### Observations (computed from this run)

{summary(steps, logging)}
"""



