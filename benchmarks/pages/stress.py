"""Numerical stability under stress (benchmarks/stress.py)."""

from __future__ import annotations

import math

import numpy as np

from . import Spec, block, figure, markdown_table

SWEEP_PLOT = 'stress_dt_sweep.png'
#: Where runs without an energy error (refused at their first step) are
#: drawn on the log scale.
PLOT_FLOOR = 1e-6


def plot(results, figures):
    _plot_sweep(results['sweeps'], figures)


def _floored(values):
    """Floats for a log plot: None (non-finite) as nan, at least PLOT_FLOOR."""
    return np.maximum([np.nan if x is None else _float(x) for x in values],
                      PLOT_FLOOR)


def _plot_sweep(sweeps, figures):
    with figure(figures / SWEEP_PLOT, len(sweeps),
                (6 * len(sweeps), 4.5)) as (plt, fig, axes):
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


def _float(value):
    return float(value)  # also parses the 'inf' stored for JSON


def _outcome(row):
    error = row['error']
    if error is None:
        return f'all {row["steps"]} steps'
    if error['type'] == 'UnstableIntegrationError':
        return f'{error["type"]} at step {error["step"]} (energy check)'
    what = error['message'].split(' is ')[0]
    return f'{error["type"]} at step {error["step"]}: {what}'


def _yes(flag):
    return 'yes' if flag else '**no**'


def _pct(value, whole):
    return f'{100 * value / whole:.3g} %'


def _quantum(kwargs):
    if not kwargs:
        return ''
    exponent = math.frexp(kwargs['position_quantum'])[1] - 1
    return f', position_quantum = 2^{exponent} Å'


def sweep_tables(sweeps):
    """Each scene of the time-step sweep: a line and its table."""
    out = []
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
    return '\n'.join(out)


def roaming_table(headers, cells):
    """A table of the evaporation or diffusion scene: ``cells`` of a row
    between its outcome and its position range."""
    def make(rows):
        table = [[r['system'] + _quantum(r['kwargs']), _outcome(r),
                  *cells(r), f'{r["x_max"]:.3g} / {r["position_range"]:.3g} '
                  f'({_pct(r["x_max"], r["position_range"])})',
                  f'{_float(r["max_energy_error"]):.2g}', _yes(r['exact'])]
                 for r in rows]
        return markdown_table(
            ['system', 'ReversibleVerlet', *headers,
             'max \\|x\\| / position range (Å)', 'max \\|ΔE\\|/K0',
             'exact'], table)
    return make


def contacts_table(rows):
    table = [[r['system'], r['calculator'], f'{r["fraction"]:g} {r["unit"]}',
              f'{r["f_max"]:.3g}', f'{r["e0"]:.3g}', _outcome(r),
              f'{r["max_energy_change"]:.3g}',
              '-' if r['first_garbage_step'] is None
              else r['first_garbage_step'],
              f'{r["vv_max_energy_change"]:.3g}',
              f'{r["p_max"]:.3g} / {r["momentum_range"]:.3g}',
              _yes(r['exact'])] for r in rows]
    return markdown_table(
        ['system', 'calculator', 'gap', 'max \\|F\\| (eV/Å)', 'E0 (eV)',
         'ReversibleVerlet', 'max \\|ΔE\\| (eV)', 'garbage from step',
         'VV max \\|ΔE\\| (eV)', 'max \\|p\\| / range at the turn',
         'exact'], table)


SPEC = Spec(
    'Numerical stability under stress',
    blocks={'sweeps': block(sweep_tables, 'sweeps'),
            'evaporation': block(roaming_table(
                ('evaporated', 'furthest from the centre (Å)'),
                lambda r: (f'{r["evaporated"]} / {r["n_atoms"]}',
                           f'{r["furthest_from_centre"]:.3g}')),
                'evaporation'),
            'contacts': block(contacts_table, 'contacts'),
            'diffusion': block(roaming_table(
                ('max displacement (cells)', 'mean displacement (cells)'),
                lambda r: (f'{r["max_cells"]:.3g}', f'{r["mean_cells"]:.3g}')),
                'diffusion')},
    plots=(plot,))
