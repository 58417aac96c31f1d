"""Reversal error against steps: VelocityVerlet's round trips against
ReversibleVerlet's, and the energy over a long run.

Measured by benchmarks/reversal_error.py, whose docstring gives the method.
"""

from __future__ import annotations

import numpy as np

from . import markdown_table, pyplot

TITLE = 'Reversal error against steps'
ERROR_PLOT = 'reversal_error.png'
ENERGY_PLOT = 'reversal_energy.png'


def plot(results, figures):
    _plot_errors(results, figures)
    _plot_energy(results, figures)


def _plot_errors(results, figures):
    plt = pyplot()
    vv = results['velocity_verlet']['points']
    ours = results['reversible']['checkpoints']
    fig, axes = plt.subplots(1, 2, figsize=(10, 4))
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
    fig.tight_layout()
    fig.savefig(figures / ERROR_PLOT, dpi=110)
    plt.close(fig)


def _plot_energy(results, figures):
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(7, 3.4))
    for key, label, color in (('velocity_verlet', 'VelocityVerlet', 'C3'),
                              ('reversible', 'ReversibleVerlet', 'C0')):
        run = results[key]
        e = np.asarray(run['energies'])
        t_ns = (np.asarray(run['energy_steps'])
                * results['system']['timestep_fs'] * 1e-6)
        ax.plot(t_ns, (e - e[0]) / abs(e[0]), lw=0.8, color=color,
                label=label)
    ax.axhline(0, color='grey', lw=0.5)
    ax.set_xlabel('time (ns)')
    ax.set_ylabel('(E - E0) / |E0|')
    ax.legend(loc='best')
    ax.set_title(f"{results['final_steps']:,} steps forward, total energy "
                 f"every {results['energy_every']} steps")
    fig.tight_layout()
    fig.savefig(figures / ENERGY_PLOT, dpi=110)
    plt.close(fig)


def _g(x):
    return f'{x:.2g}' if x else '0'


def markdown_energy(en) -> str:
    rows = []
    for key, label in (('reversible', 'ReversibleVerlet'),
                       ('velocity_verlet', 'VelocityVerlet')):
        e = en[key]
        rows.append([label, _g(e['max_relative_deviation']),
                     _g(e['max_relative_deviation_first_tenth']),
                     _g(e['max_relative_deviation_last_tenth']),
                     f"{e['mean_last_tenth'] - e['mean_first_tenth']:.2g}",
                     f"{_g(e['std_first_tenth'])} / {_g(e['std_last_tenth'])}",
                     f"{e['mean_shift_in_std']:.2g}",
                     f"{e['drift_eV_per_ns']:.2g}"])
    n = en['reversible']['samples_per_tenth']
    return (f'E0 = {en["reversible"]["e0"]:.9g} eV (ReversibleVerlet), '
            f'{en["velocity_verlet"]["e0"]:.9g} eV (VelocityVerlet). A tenth '
            f'of the run is {n} samples.\n\n' + markdown_table(
                ['integrator', 'max \\|E-E0\\|/\\|E0\\|',
                 'same, first tenth', 'same, last tenth',
                 'mean(last tenth) - mean(first tenth) (eV)',
                 'std first / last tenth (eV)',
                 'mean shift / first-tenth std', 'fitted drift (eV/ns)'],
                rows))


def markdown(results) -> str:
    s = results['system']
    vv = results['velocity_verlet']
    ours = results['reversible']
    en = results['energy']
    sh = ours['shape_at_turn']
    vsh = vv['shape_at_end']
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
    all_exact = all(c['exact'] for c in ours['checkpoints'])
    all_resumed = all(c['resumed_exactly'] for c in ours['checkpoints'][:-1])
    vv_last = vv['points'][-1]
    return f"""
Ar{s['atoms']} icosahedron thermalised at {s['temperature_K']:g} K (seed
{s['seed']}), {s['calculator']}, {s['timestep_fs']:g} fs, in a periodic cube
of edge {s['cell_edge']:.1f} Å: the cluster ({2 * s['cluster_radius_start']:.1f} Å
across at the start) does not interact with its images, and atoms that
evaporate stay nearby as vapour. (With free boundaries, an evaporated atom
flies off and asap3's neighbour list grows with the box enclosing all
atoms, and the cost of a step grows with it.) N steps forward, then N steps
with the time step negated; the error is the largest coordinate difference
from the start.
Both integrators start from the same state (the one ReversibleVerlet's
constructor put on its grid: position quantum {results['grid']['position_quantum']:.3g} Å,
momentum quantum {results['grid']['momentum_quantum']:.3g} amu Å / ASE time).

![reversal error](benchmarks/{ERROR_PLOT})

### Method

- VelocityVerlet: one forward run; at each N a copy of the atoms with a
  fresh asap3 calculator runs N steps back. The forward run keeps its own
  calculator, so it is one uninterrupted trajectory; the backward leg starts
  from a neighbour list built at the turning point rather than the one the
  forward run last used. The forward run goes on to
  {results['final_steps']:,} steps for its energy only.
  {vv['steps_run']:,} steps in {vv['seconds']:.0f} s
  ({vv['seconds_per_step'] * 1e6:.0f} µs/step).
- ReversibleVerlet: one integrator and only its public API. At each N it
  reverses, runs N steps, is compared with the start by `np.array_equal` on
  positions and momenta, reverses again and runs N steps forward, where it
  met the saved state bitwise at every N: {all_resumed}. Then it goes on to
  {results['final_steps']:,} steps and back. {ours['steps_run']:,} steps in
  {ours['seconds']:.0f} s ({ours['seconds_per_step'] * 1e6:.0f} µs/step),
  force purity `{ours['force_purity']}`: {ours['clean_recomputations']:,}
  clean recomputations, largest noise removed
  {_g(ours['max_observed_noise'])} eV/Å (the bound exactness relies on:
  {_g(ours['force_noise_bound'])} eV/Å).

### Results

| N | VelocityVerlet max \\|Δx\\| (Å) | VelocityVerlet max \\|Δp\\| (amu Å / ASE time) | ReversibleVerlet max \\|Δx\\| / \\|Δp\\| | ReversibleVerlet bitwise equal |
| --- | --- | --- | --- | --- |
""" + '\n'.join('| ' + ' | '.join(r) + ' |' for r in rows) + f"""

ReversibleVerlet returned to the start bit for bit at every N: {all_exact}.
VelocityVerlet after {vv_last['steps']:,} steps each way is
{_g(vv_last['position_error'])} Å from the start; the cluster's diameter at
the start is {_g(2 * s['cluster_radius_start'])} Å.

### Energy over the {results['final_steps']:,}-step run

![energy](benchmarks/{ENERGY_PLOT})

Total energy along the forward runs, read every
{results['energy_every']:,} steps ({en['reversible']['duration_ns']:.3g} ns).
VelocityVerlet ran the same length from the same start as the reference:
the two trajectories part after a few thousand steps (the table above), so
only their statistics compare.

""" + markdown_energy(en) + f"""

After the {results['final_steps']:,} forward steps the centre of mass had
moved {sh['centre_displacement']:.3g} Å in ReversibleVerlet's run
({vsh['centre_displacement']:.3g} Å in VelocityVerlet's; the thermalised
momenta carry a net momentum), and {sh['isolated_atoms']}
({vsh['isolated_atoms']}) atoms had no neighbour within the {s['cutoff']:g} Å
cutoff: evaporated, a vapour in the periodic box.
"""
