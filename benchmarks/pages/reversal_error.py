"""Reversal error against steps (benchmarks/reversal_error.py)."""

from __future__ import annotations

import numpy as np

from . import Spec, block, figure, markdown_table

ERROR_PLOT = 'reversal_error.png'


def plot(results, figures):
    with figure(figures / ERROR_PLOT, 2, (10, 4)) as (plt, fig, axes):
        vv = results['velocity_verlet']['points']
        ours = results['reversible']['checkpoints']
        for ax, key, symbol, unit in (
                (axes[0], 'position_error', 'x', 'Å'),
                (axes[1], 'momentum_error', 'p', 'amu Å / ASE time')):
            n = [p['steps'] for p in vv]
            err = [p[key] for p in vv]
            ax.plot(n, err, 'o-', color='C3', label='VelocityVerlet')
            ax.plot([c['steps'] for c in ours], [c[key] for c in ours], 's-',
                    color='C0', label='ReversibleVerlet')
            positive = [e for e in err if e > 0]
            # Zero has to sit on the axis itself: symlog, linear just below the
            # smallest VelocityVerlet error.
            threshold = 10.0 ** np.floor(np.log10(min(positive))) / 10 \
                if positive else 1e-16
            ax.set_yscale('symlog', linthresh=threshold, linscale=0.5)
            ax.axhline(0, color='C0', lw=0.5)
            ax.set_xscale('log')
            ax.set_xlabel('steps N forward, then N back')
            ax.set_ylabel(f'max |{symbol} - {symbol}0| ({unit})')
            ax.grid(True, which='major', alpha=0.3)
            top = max(err + [threshold])
            ax.set_ylim(-threshold / 2, top * 30)
            low, high = int(np.log10(threshold)), int(np.ceil(np.log10(top * 30)))
            ax.set_yticks([0] + [10.0 ** k for k in range(low, high + 1, 3)])
            ax.annotate('ReversibleVerlet: exactly 0', xy=(0.98, 0.06),
                        xycoords='axes fraction', ha='right', color='C0')
        axes[0].axhline(2 * results['system']['cluster_radius_start'],
                        color='grey', ls=':', label='cluster diameter at start')
        axes[0].legend(loc='upper left')
        s = results['system']
        fig.suptitle(f"Ar{s['atoms']}, {s['temperature_K']:g} K, asap3 LJ, "
                     f"{s['timestep_fs']:g} fs: distance from the start after a "
                     'round trip')


def _g(x):
    return f'{x:.2g}' if x else '0'


def errors_table(results) -> str:
    """Both integrators' distance from the start after N steps and back."""
    vv, ours = results['velocity_verlet'], results['reversible']
    by_n = {c['steps']: c for c in ours['checkpoints']}
    rows = []
    for p in vv['points']:
        c = by_n.get(p['steps'])
        rows.append([f"{p['steps']:,}", _g(p['position_error']),
                     _g(p['momentum_error']),
                     _g(c['position_error']) + ' / ' + _g(c['momentum_error'])
                     if c else '-', str(c['exact']) if c else '-'])
    final = ours['checkpoints'][-1]
    if final['steps'] not in {p['steps'] for p in vv['points']}:
        rows.append([f"{final['steps']:,}", 'not run', 'not run',
                     _g(final['position_error']) + ' / '
                     + _g(final['momentum_error']), str(final['exact'])])
    return markdown_table(
        ['N', 'VelocityVerlet max \\|Δx\\| (Å)',
         'VelocityVerlet max \\|Δp\\| (amu Å / ASE time)',
         'ReversibleVerlet max \\|Δx\\| / \\|Δp\\|',
         'ReversibleVerlet bitwise equal'], rows)


def values(results):
    """The prose's derived numbers."""
    s, vv, ours = (results['system'], results['velocity_verlet'],
                   results['reversible'])
    return {'diameter': 2 * s['cluster_radius_start'],
            'vv_us': vv['seconds_per_step'] * 1e6,
            'ours_us': ours['seconds_per_step'] * 1e6,
            'all_exact': all(c['exact'] for c in ours['checkpoints']),
            'all_resumed': all(c['resumed_exactly']
                               for c in ours['checkpoints'][:-1]),
            'noise': _g(ours['max_observed_noise']),
            'bound': _g(ours['force_noise_bound']),
            'vv_last': vv['points'][-1]['steps'],
            'vv_last_error': _g(vv['points'][-1]['position_error']),
            'diameter_g': _g(2 * s['cluster_radius_start'])}


SPEC = Spec('Reversal error against steps',
            blocks={'errors': block(errors_table)},
            plots=(plot,), values=values)
