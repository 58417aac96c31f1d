"""Numerical stability under stress: blow-ups, evaporation, close contacts,
diffusion, asap3 with atoms far apart.

Measured by benchmarks/stress.py, whose docstring describes the scenes.
"""

from __future__ import annotations

import math

import numpy as np

from . import markdown_table, pyplot

TITLE = 'Numerical stability under stress'
SWEEP_PLOT = 'stress_dt_sweep.png'
TRACES_PLOT = 'stress_blowup_traces.png'
#: Where runs without an energy error (refused at their first step) are
#: drawn on the log scale.
PLOT_FLOOR = 1e-6


def plot(results, figures):
    _plot_sweep(results['sweeps'], figures)
    # Results stored before the traces were kept have none: their plot
    # stays as it was drawn at measurement time.
    if all('trace' in result for result in results['sweeps']):
        _plot_traces(results['sweeps'], figures)


def _floored(values):
    """Floats for a log plot: None (non-finite) as nan, at least PLOT_FLOOR."""
    return np.maximum([np.nan if x is None else _float(x) for x in values],
                      PLOT_FLOOR)


def _plot_sweep(sweeps, figures):
    plt = pyplot()
    fig, axes = plt.subplots(1, len(sweeps), figsize=(6 * len(sweeps), 4.5))
    for ax, result in zip(np.atleast_1d(axes), sweeps):
        rows = result['rows']
        dts = [r['dt_fs'] for r in rows]
        # Runs stopped before their first step have no error to show:
        # they sit on the floor of the plot, labelled with the step.
        ours = list(_floored(r['max_energy_error'] for r in rows))
        vv = list(np.minimum(_floored(r['vv']['max_energy_error']
                                      for r in rows), 1e30))
        ax.plot(dts, vv, 's-', color='0.5', label='VelocityVerlet')
        ax.plot(dts, ours, '-', color='C0', lw=1)
        done = [r['error'] is None for r in rows]
        ax.plot([d for d, ok in zip(dts, done) if ok],
                [e for e, ok in zip(ours, done) if ok], 'o', color='C0',
                label=f'ReversibleVerlet, all {result["steps"]} steps')
        ax.plot([d for d, ok in zip(dts, done) if not ok],
                [e for e, ok in zip(ours, done) if not ok], 'X', color='C3',
                ms=9, label='ReversibleVerlet, stopped by an error')
        stopped = [(r, e) for r, e in zip(rows, ours)
                   if r['error'] is not None]
        for i, (row, e) in enumerate(stopped):
            # Alternate above and below: neighbouring labels overlap.
            ax.annotate(f'step {row["error"]["step"]}', (row['dt_fs'], e),
                        textcoords='offset points',
                        xytext=(4, -12 if i % 2 == 0 else 8),
                        fontsize=7, color='C3')
        ax.axhline(1.0, color='k', ls=':', lw=1)
        ax.set_xscale('log')
        ax.set_yscale('log')
        ax.set_xlabel('time step (fs)')
        ax.set_ylabel('max |E - E0| / K0 over the run')
        ax.set_title(f'{result["name"]}, {result["calculator"]}',
                     fontsize=10)
        ax.legend(fontsize=8, loc='upper left')
    fig.tight_layout()
    fig.savefig(figures / SWEEP_PLOT, dpi=110)
    plt.close(fig)


def _plot_traces(sweeps, figures):
    """Energy error step by step in the run of each system that started
    sane and then spent the most steps with |E - E0| > K0."""
    plt = pyplot()
    fig, axes = plt.subplots(1, len(sweeps), figsize=(6 * len(sweeps), 4))
    for ax, result in zip(np.atleast_1d(axes), sweeps):
        row = next(r for r in result['rows']
                   if r['dt_fs'] == result['traced_dt_fs'])
        trace = result['trace']
        ax.plot(_floored(trace['velocity_verlet']), color='0.6', lw=4,
                alpha=0.6, label='VelocityVerlet')
        ax.plot(_floored(trace['reversible']), color='C0',
                label='ReversibleVerlet')
        if row['error'] is not None:
            ax.axvline(row['error']['step'], color='C3', ls='--',
                       label=f'{row["error"]["type"]} (step '
                             f'{row["error"]["step"]})')
        ax.axhline(1.0, color='k', ls=':', lw=1)
        ax.set_yscale('log')
        ax.set_xlabel('step')
        ax.set_ylabel('|E - E0| / K0')
        ax.set_title(f'{result["name"]}, {result["calculator"]}, '
                     f'dt = {row["dt_fs"]:g} fs', fontsize=10)
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(figures / TRACES_PLOT, dpi=110)
    plt.close(fig)


def _float(value):
    return float(value)  # also parses the 'inf' stored for JSON


def _what(error):
    """The short reason of an error: what left its range, or the check."""
    if error['type'] == 'UnstableIntegrationError':
        return 'the energy check'
    return error['message'].split(' of atom')[0]


def _outcome(row):
    error = row['error']
    if error is None:
        return f'all {row["steps"]} steps'
    if error['type'] == 'UnstableIntegrationError':
        return f'{error["type"]} at step {error["step"]} (energy check)'
    what = error['message'].split(' is ')[0]
    return f'{error["type"]} at step {error["step"]}: {what}'


def _steps(n):
    return f'{n} step' + ('' if n == 1 else 's')


def _yes(flag):
    return 'yes' if flag else '**no**'


def _pct(value, whole):
    return f'{100 * value / whole:.3g} %'


def _quantum(kwargs):
    if not kwargs:
        return ''
    exponent = math.frexp(kwargs['position_quantum'])[1] - 1
    return f', position_quantum = 2^{exponent} Å'


def markdown(results):
    settings = results['settings']
    out = [
        'Each scene runs ReversibleVerlet forward, then reverses it and runs '
        'back as many steps as it completed (all of them, or those before '
        'an error), and checks that positions and momenta are those right '
        'after the constructor, bit for bit ("exact"). Energy errors are '
        '`max |E - E0|` over the committed steps divided by the initial '
        'kinetic energy `K0`: above 1 the error exceeds all the thermal '
        f'energy the run started with. Time step {settings["dt_fs"]:g} fs '
        'unless a table says otherwise; default quanta unless a row gives '
        '`position_quantum`.',
        '']
    out += _render_sweep(results['sweeps'], settings)
    out += _render_evaporation(results['evaporation'])
    out += _render_contacts(results['contacts'], settings)
    out += _render_diffusion(results['diffusion'])
    out += _render_far_apart(results['far_apart'])
    return '\n'.join(out)


def _render_sweep(sweeps, settings):
    out = ['### Time step far past the stability limit', '',
           f'![energy error against time step](benchmarks/{SWEEP_PLOT})',
           '',
           'A run refused at its first step committed nothing: it has no '
           f'energy error and is drawn at {PLOT_FLOOR:g}. "Steps with '
           '|ΔE| > K0" counts committed steps from the first such step to '
           'the last committed one.', '']
    for result in sweeps:
        rows = result['rows']
        out += [f'**{result["name"]}, {result["calculator"]}**, '
                f'{result["steps"]} steps per run.', '']
        table = []
        for r in rows:
            vv = r['vv']
            table.append([
                f'{r["dt_fs"]:g}', _outcome(r | {'steps': result['steps']}),
                f'{_float(r["max_energy_error"]):.3g}',
                '-' if r['first_garbage_step'] is None
                else r['first_garbage_step'],
                r['silent_steps'], r.get('steps_beyond_tolerance', '?'),
                _yes(r['exact']),
                f'{r["p_max"]:.3g} / {r["momentum_range"]:.3g}',
                f'{_float(vv["max_energy_error"]):.3g}'
                + (' (non-finite)' if vv['non_finite'] else ''),
                '-' if vv['first_garbage_step'] is None
                else vv['first_garbage_step'],
                f'{_float(vv["x_max"]):.3g}'])
        out += [markdown_table(
            ['dt (fs)', 'ReversibleVerlet', 'max \\|ΔE\\|/K0',
             'first step \\|ΔE\\| > K0', 'steps with \\|ΔE\\| > K0',
             'steps beyond tolerance', 'exact', 'max \\|p\\| / range at the turn',
             'VV max \\|ΔE\\|/K0', 'VV first step \\|ΔE\\| > K0',
             'VV max \\|x\\| (Å)'], table), '']
        sane = []
        for r in rows:
            if r['first_garbage_step'] is not None or r['error'] is not None:
                break
            sane.append(r['dt_fs'])
        stopped = [r for r in rows if r['error'] is not None]
        silent = [r for r in rows if r['silent_steps'] > 0]
        text = []
        if sane:
            text.append(f'ReversibleVerlet completed every run with |ΔE| < '
                        f'K0 up to {sane[-1]:g} fs.')
        if stopped:
            kinds = sorted({f'{r["error"]["type"]}: {_what(r["error"])}'
                            for r in stopped})
            text.append('It stopped at '
                        + ', '.join(f'{r["dt_fs"]:g}' for r in stopped)
                        + ' fs (' + '; '.join(kinds) + ').')
        counted = [r['steps_beyond_tolerance'] for r in rows
                   if 'steps_beyond_tolerance' in r]
        if counted:
            text.append(f'No run committed more than {max(counted)} '
                        f'step{"s" if max(counted) != 1 else ""} beyond the '
                        "energy check's tolerance.")
        text.append('Every run, completed or stopped, ran back exactly.'
                    if all(r['exact'] for r in rows)
                    else '**Some runs did not run back exactly.**')
        vv_bad = [r for r in rows if r['vv']['first_garbage_step'] is not None]
        if vv_bad:
            worst = max(vv_bad,
                        key=lambda r: _float(r['vv']['max_energy_error']))
            raised = [r for r in rows if r['vv']['error'] is not None]
            text.append(
                ('VelocityVerlet raised nothing in any run; '
                 if not raised else 'VelocityVerlet raised '
                 + ', '.join(f'{r["vv"]["error"]["type"]} at '
                             f'{r["dt_fs"]:g} fs' for r in raised) + '; ')
                + 'its energy error exceeded K0 at '
                + ', '.join(f'{r["dt_fs"]:g}' for r in vv_bad)
                + ' fs and reached '
                f'{_float(worst["vv"]["max_energy_error"]):.3g} K0 '
                f'at {worst["dt_fs"]:g} fs, with atoms '
                f'{_float(worst["vv"]["x_max"]):.3g} Å from the origin'
                + (', and non-finite energies.' if any(
                    r['vv']['non_finite'] for r in rows) else
                   ' (all energies finite).'))
        if silent:
            text.append(
                f'In {len(silent)} of {len(rows)} runs ReversibleVerlet '
                'committed steps with |ΔE| > K0 before it stopped or the run '
                'ended: ' + '; '.join(
                    f'{r["dt_fs"]:g} fs: {_steps(r["silent_steps"])} from step '
                    f'{r["first_garbage_step"]}, up to '
                    f'{_float(r["max_energy_error"]):.3g} K0, then '
                    + ('finished' if r['error'] is None else
                       f'stopped at step {r["error"]["step"]}')
                    for r in silent) + '.')
        out += [' '.join(text), '']
    out += ['![energy error step by step in the longest silent window]'
            f'(benchmarks/{TRACES_PLOT})', '',
            'Two detectors stop a blow-up. A step is refused when a momentum '
            'or position (or its increment) would leave the fixed-point '
            'range, which by default is '
            f"{settings['momentum_room']:g} times the larger of the initial "
            'momenta and the thermal momentum at '
            f"{settings['momentum_temperature_floor']:g} K, and "
            f"{settings['position_room']:g} times the system size; with the "
            'guarded force purity (asap3) the momentum quantum is coarser and '
            'the momentum range much wider (column "max |p| / range"). And '
            'the energy check compares the total energy with its start at '
            'steps 1, 2, 4, ... and then every '
            f"{settings['energy_check_interval']} steps, against the larger "
            'of the initial kinetic energy and that of the atoms at '
            f"{settings['energy_tolerance_temperature']:g} K, and in between "
            'whenever the kinetic energy (read every second step) has moved '
            'by half the tolerance or the last check found the drift past '
            'half of it. Column "steps beyond tolerance" counts the committed '
            'steps whose |E - E0| exceeded that tolerance: the check promises '
            'at most two.', '']
    return out


def _render_evaporation(rows):
    out = ['### Hot, evaporating clusters', '',
           'ASE LennardJones (cutoff 8.5 Å). "Evaporated" counts atoms whose '
           'nearest neighbour at the turn is beyond the cutoff.', '']
    table = [[r['system'] + _quantum(r['kwargs']),
              _outcome(r), f'{r["evaporated"]} / {r["n_atoms"]}',
              f'{r["furthest_from_centre"]:.3g}',
              f'{r["x_max"]:.3g} / {r["position_range"]:.3g} '
              f'({_pct(r["x_max"], r["position_range"])})',
              f'{_float(r["max_energy_error"]):.2g}', _yes(r['exact'])]
             for r in rows]
    out += [markdown_table(
        ['system', 'ReversibleVerlet', 'evaporated', 'furthest from the '
         'centre (Å)', 'max \\|x\\| / position range (Å)',
         'max \\|ΔE\\|/K0', 'exact'], table), '']
    return out


def _render_contacts(rows, settings):
    out = ['### Close contacts', '',
           'Two atoms at rest, or atom 0 of perfect Cu bulk moved towards its '
           'nearest neighbour, at the given fraction of σ '
           f"({settings['ar_sigma']} Å) or of the Cu bond "
           f"({settings['cu_bond']:.3f} Å). ΔE is the "
           'total-energy change '
           'over the committed steps, in eV, and "garbage from" the first '
           'step where |ΔE| exceeds |E0|.', '']
    table = [[r['system'], r['calculator'], f'{r["fraction"]:g} {r["unit"]}',
              f'{r["f_max"]:.3g}', f'{r["e0"]:.3g}', _outcome(r),
              f'{r["max_energy_change"]:.3g}',
              '-' if r['first_garbage_step'] is None
              else r['first_garbage_step'],
              f'{r["vv_max_energy_change"]:.3g}',
              f'{r["p_max"]:.3g} / {r["momentum_range"]:.3g}',
              _yes(r['exact'])] for r in rows]
    out += [markdown_table(
        ['system', 'calculator', 'gap', 'max \\|F\\| (eV/Å)', 'E0 (eV)',
         'ReversibleVerlet', 'max \\|ΔE\\| (eV)', 'garbage from step',
         'VV max \\|ΔE\\| (eV)', 'max \\|p\\| / range at the turn',
         'exact'], table), '']
    refused = [r for r in rows if r['error'] is not None
               and r['steps_done'] == 0]
    garbage = [r for r in rows if r['first_garbage_step'] is not None]
    text = []
    if refused:
        text.append(f'{len(refused)} of {len(rows)} contacts were refused at '
                    'the first step with a range error on the momentum '
                    f'increment (max |F| from '
                    f'{min(r["f_max"] for r in refused):.3g} eV/Å), the '
                    'state unchanged.')
    if garbage:
        text.append(
            f'{len(garbage)} ran on with |ΔE| > |E0|: the '
            f'{settings["dt_fs"]:g} fs step '
            'does not resolve the collision, in VelocityVerlet either: '
            + '; '.join(
                f'{r["system"]} {r["calculator"]} at {r["fraction"]:g} '
                f'{r["unit"]}: from step {r["first_garbage_step"]}, up to '
                f'{r["max_energy_change"]:.3g} eV from E0 = {r["e0"]:.3g} eV, '
                + ('all steps' if r['error'] is None else
                   f'stopped at step {r["error"]["step"]}')
                for r in garbage) + '.')
    text.append('All runs ran back exactly.' if all(r['exact'] for r in rows)
                else '**Not every run ran back exactly.**')
    return out + [' '.join(text), '']


def _render_diffusion(rows):
    out = ['### Periodic diffusion over many cell lengths', '',
           'ASE LennardJones (cutoff 8.5 Å, more than half the cell). '
           'Displacements are unwrapped: ReversibleVerlet never wraps '
           'positions into the cell, so they count against the position '
           'range.', '']
    table = [[r['system'] + _quantum(r['kwargs']),
              _outcome(r), f'{r["max_cells"]:.3g}', f'{r["mean_cells"]:.3g}',
              f'{r["x_max"]:.3g} / {r["position_range"]:.3g} '
              f'({_pct(r["x_max"], r["position_range"])})',
              f'{_float(r["max_energy_error"]):.2g}', _yes(r['exact'])]
             for r in rows]
    out += [markdown_table(
        ['system', 'ReversibleVerlet', 'max displacement (cells)',
         'mean displacement (cells)', 'max \\|x\\| / position range (Å)',
         'max \\|ΔE\\|/K0', 'exact'], table), '']
    return out


def _render_far_apart(result):
    out = ['### asap3 with atoms far apart in a free cluster', '',
           'Ar13 with two atoms moved by ±d along (1, 1, 1), one force call '
           f'in a subprocess limited to {result["memory_limit_gib"]:g} GiB '
           'of address space. The default position range ReversibleVerlet '
           'chooses for this cluster is '
           f'±{result["default_position_range"]:.3g} Å.', '']
    table = []
    for r in result['rows']:
        if r['returncode'] == 0:
            what = (f'forces in {r["seconds"]:.3g} s, peak RSS '
                    f'{r["max_rss_mb"]:.0f} MB')
        else:
            what = (f'**process aborted** (exit code {r["returncode"]}): '
                    + ' '.join(r['stderr']))
        table.append([r['calculator'], f'{r["distance"]:g}',
                      f'{r["spread"]:.3g}', what])
    out += [markdown_table(['calculator', 'd (Å)',
                                   'distance between them (Å)', 'result'],
                                  table), '']
    aborted = [r for r in result['rows'] if r['returncode'] != 0]
    if aborted:
        first = min(aborted, key=lambda r: r['distance'])
        out += [f'asap3\'s memory grows with the extent of the atoms in a '
                f'non-periodic cell (peak RSS above). With atoms '
                f'{first["spread"]:.3g} Å apart, coordinates up to '
                f'{first["x_max"]:.3g} Å, inside the default position '
                'range, a C++ allocation fails and the process is aborted; '
                'no Python exception reaches ReversibleVerlet. An evaporating '
                'or blown-up free '
                'cluster under asap3 can therefore crash before a '
                'QuantumRangeError; ASE\'s LennardJones does not have this '
                'limit.', '']
    return out
