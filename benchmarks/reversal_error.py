"""Reversal error against the number of steps, and a 10^6-step round trip.

System: the Ar147 icosahedron at 120 K with asap3's LennardJones and a 5 fs
time step, the case of the VelocityVerlet measurement this section repeats,
but in a periodic box (see make_cluster) so that the 10^6-step run stays
affordable after atoms evaporate.
Both integrators start from the same state: the one ReversibleVerlet's
constructor put on its grid.

VelocityVerlet.  One forward run visits N = 125, 250, ..., doubling.  At
each N a copy of the atoms, with a fresh asap3 calculator, runs N steps with
the time step negated, and its distance from the start is measured.  The
forward run keeps its own calculator and is never disturbed, so it is the
trajectory of one uninterrupted run; the backward leg starts with a
neighbour list built at the turning point, where an uninterrupted round trip
would carry the list of the last forward steps.  Both are honest
VelocityVerlet runs, and the difference is force noise at 1e-15 eV/Å, far
below the errors measured here.  This costs N per point instead of a whole
new round trip.

ReversibleVerlet.  One integrator, through the public API only.  At each N
of the same grid it reverses, runs N steps, is compared bitwise with the
start, reverses again and runs N steps forward, where it must meet the state
saved at N bit for bit; then it goes on.  After the grid it runs on to the
final length (10^6 steps in the full mode) and back.  The total energy is
read every few steps on the forward run only: the velocity scheme leaves
it cached after each step, so reading it costs nothing.
"""

from __future__ import annotations

import common  # noqa: F401  (first: pins BLAS threads before numpy)

import time

import numpy as np
from asap3 import LennardJones
from ase import units
from ase.cluster import Icosahedron
from ase.geometry import get_distances
from ase.md.verlet import VelocityVerlet

from ase_reversible import ReversibleVerlet

TITLE = 'Reversal error against steps'

ATOMS, SHELLS, TEMPERATURE_K, TIMESTEP_FS, SEED = 147, 4, 120.0, 5.0, 0
AR_EPSILON, AR_SIGMA, AR_CUTOFF, AR_LATTICE = 0.0104, 3.4, 8.5, 5.26
VACUUM = 10.0

# (checkpoints, final length, energy interval) per mode.  The grid doubles
# from 125 so that it passes through N = 1000, 4000 and 16000.
QUICK = dict(grid=[125 * 2 ** k for k in range(7)],          # ... 8000
             final=8000, energy_every=100)
FULL = dict(grid=[125 * 2 ** k for k in range(11)],          # ... 128000
            final=1_000_000, energy_every=1000)


def make_cluster():
    atoms = Icosahedron('Ar', SHELLS, latticeconstant=AR_LATTICE)
    assert len(atoms) == ATOMS
    # Periodic, in a box the cluster cannot see its images through (edge
    # minus cluster size > cutoff).  With free boundaries an atom that
    # evaporates (one does after about 2.3e5 steps) flies off, and asap3's
    # neighbour list grows with the box enclosing all atoms: at 5e5 steps
    # the step cost was 13 times the start's and growing.  In the box the
    # vapour stays near the cluster.
    atoms.center(vacuum=VACUUM)
    atoms.pbc = True
    common.thermalised(atoms, TEMPERATURE_K, SEED)
    atoms.calc = fresh_calculator()
    return atoms


def fresh_calculator():
    return LennardJones([18], [AR_EPSILON], [AR_SIGMA], rCut=AR_CUTOFF,
                        modified=True)


def largest_difference(atoms, x0, p0):
    return (float(np.abs(atoms.get_positions() - x0).max()),
            float(np.abs(atoms.get_momenta() - p0).max()))


def velocity_verlet_curve(x0, p0, grid, dt):
    twin = make_cluster()
    twin.set_positions(x0)
    twin.set_momenta(p0)
    forward = VelocityVerlet(twin, dt)
    points = []
    backward_steps = 0
    tic = time.perf_counter()
    for n in grid:
        forward.run(n - forward.nsteps)
        back = twin.copy()
        back.calc = fresh_calculator()
        VelocityVerlet(back, -dt).run(n)
        backward_steps += n
        dx, dp = largest_difference(back, x0, p0)
        points.append({'steps': n, 'position_error': dx,
                       'momentum_error': dp})
    seconds = time.perf_counter() - tic
    return {'points': points, 'seconds': seconds,
            'steps_run': grid[-1] + backward_steps,
            'seconds_per_step': seconds / (grid[-1] + backward_steps)}


def reversible_run(atoms, dyn, x0, p0, grid, final, energy_every):
    e0 = atoms.get_total_energy()
    energies = [(0, e0)]
    checkpoints = []
    steps_run = 0
    stops = sorted(set(grid) | {final}
                   | set(range(energy_every, final + 1, energy_every)))
    position = 0
    tic = time.perf_counter()
    for stop in stops:
        dyn.run(stop - position)
        steps_run += stop - position
        position = stop
        if stop % energy_every == 0:
            energies.append((stop, atoms.get_total_energy()))
        if stop in grid and stop != final:
            x_turn, p_turn = atoms.get_positions(), atoms.get_momenta()
            dyn.reverse()
            dyn.run(stop)
            exact = (np.array_equal(atoms.get_positions(), x0)
                     and np.array_equal(atoms.get_momenta(), p0))
            dx, dp = largest_difference(atoms, x0, p0)
            dyn.reverse()
            dyn.run(stop)
            steps_run += 2 * stop
            # Going on from anything but the saved state would make the
            # later points test a different trajectory.
            resumed = (np.array_equal(atoms.get_positions(), x_turn)
                       and np.array_equal(atoms.get_momenta(), p_turn))
            checkpoints.append({'steps': stop, 'exact': bool(exact),
                                'position_error': dx, 'momentum_error': dp,
                                'resumed_exactly': bool(resumed)})
    shape = cluster_shape(atoms, x0)
    dyn.reverse()
    dyn.run(final)
    steps_run += final
    seconds = time.perf_counter() - tic
    exact = (np.array_equal(atoms.get_positions(), x0)
             and np.array_equal(atoms.get_momenta(), p0))
    dx, dp = largest_difference(atoms, x0, p0)
    checkpoints.append({'steps': final, 'exact': bool(exact),
                        'position_error': dx, 'momentum_error': dp,
                        'resumed_exactly': None})
    purity = dyn.force_purity
    return {
        'checkpoints': checkpoints,
        'energy_steps': [s for s, _ in energies],
        'energies': [float(e) for _, e in energies],
        'seconds': seconds, 'steps_run': steps_run,
        'seconds_per_step': seconds / steps_run,
        'shape_at_turn': shape,
        'force_purity': purity.mode,
        'clean_recomputations': getattr(purity, 'clean_recomputations', None),
        'max_observed_noise': getattr(purity, 'max_observed_noise', None),
    }


def cluster_shape(atoms, x0):
    """How far the cluster drifted, and how many atoms are vapour."""
    x = atoms.get_positions()
    _, distances = get_distances(x, cell=atoms.cell, pbc=atoms.pbc)
    np.fill_diagonal(distances, np.inf)
    return {
        # Thermalised momenta sum to a net momentum: the whole cluster
        # drifts through the periodic box, harmlessly.
        'centre_displacement': float(np.linalg.norm(x.mean(axis=0)
                                                    - x0.mean(axis=0))),
        'isolated_atoms': int(np.sum(distances.min(axis=1) > AR_CUTOFF)),
    }


def energy_summary(steps, energies, dt_fs):
    steps = np.asarray(steps)
    e = np.asarray(energies)
    e0 = e[0]
    rel = (e - e0) / abs(e0)
    tenth = max(len(e) // 10, 2)
    first, last = e[1:tenth + 1], e[-tenth:]
    t_ns = steps * dt_fs * 1e-6
    slope = float(np.polyfit(t_ns, e, 1)[0])
    spread = float(first.std())
    return {
        'e0': float(e0),
        'max_relative_deviation': float(np.abs(rel).max()),
        'max_relative_deviation_first_tenth': float(np.abs(rel[1:tenth + 1]).max()),
        'max_relative_deviation_last_tenth': float(np.abs(rel[-tenth:]).max()),
        'mean_first_tenth': float(first.mean()), 'std_first_tenth': spread,
        'mean_last_tenth': float(last.mean()),
        'std_last_tenth': float(last.std()),
        'samples_per_tenth': int(tenth),
        'mean_shift_in_std': float((last.mean() - first.mean()) / spread),
        'drift_eV_per_ns': slope,
        'duration_ns': float(t_ns[-1]),
    }


def run(quick: bool, figures):
    mode = QUICK if quick else FULL
    dt = TIMESTEP_FS * units.fs
    atoms = make_cluster()
    dyn = ReversibleVerlet(atoms, dt)
    x0, p0 = atoms.get_positions(), atoms.get_momenta()
    grid = [n for n in mode['grid'] if n <= mode['final']]
    radius0 = float(np.linalg.norm(x0 - x0.mean(axis=0), axis=1).max())

    vv = velocity_verlet_curve(x0, p0, grid, dt)
    ours = reversible_run(atoms, dyn, x0, p0, grid, mode['final'],
                          mode['energy_every'])
    energy = energy_summary(ours['energy_steps'], ours['energies'],
                            TIMESTEP_FS)
    results = {
        'system': {'atoms': ATOMS, 'temperature_K': TEMPERATURE_K,
                   'timestep_fs': TIMESTEP_FS, 'seed': SEED,
                   'calculator': 'asap3 LennardJones (rCut 8.5 Å, modified)',
                   'cluster_radius_start': radius0,
                   'cell_edge': float(atoms.cell.lengths()[0])},
        'grid': {'position_quantum': dyn.grid.position_quantum,
                 'momentum_quantum': dyn.grid.momentum_quantum},
        'final_steps': mode['final'],
        'energy_every': mode['energy_every'],
        'velocity_verlet': vv,
        'reversible': ours,
        'energy': energy,
    }
    results['plots'] = [_plot_errors(results, figures),
                        _plot_energy(results, figures)]
    return results


def _plot_errors(results, figures):
    plt = common.pyplot()
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
    if results['system']['cluster_radius_start']:
        axes[0].axhline(2 * results['system']['cluster_radius_start'],
                        color='grey', ls=':', label='cluster diameter')
    axes[0].legend(loc='upper left')
    s = results['system']
    fig.suptitle(f"Ar{s['atoms']}, {s['temperature_K']:g} K, asap3 LJ, "
                 f"{s['timestep_fs']:g} fs: distance from the start after a "
                 'round trip')
    fig.tight_layout()
    name = 'reversal_error.png'
    fig.savefig(figures / name, dpi=110)
    plt.close(fig)
    return name


def _plot_energy(results, figures):
    plt = common.pyplot()
    ours = results['reversible']
    e = np.asarray(ours['energies'])
    t_ns = np.asarray(ours['energy_steps']) * TIMESTEP_FS * 1e-6
    fig, ax = plt.subplots(figsize=(7, 3.2))
    ax.plot(t_ns, (e - e[0]) / abs(e[0]), lw=0.8)
    ax.axhline(0, color='grey', lw=0.5)
    ax.set_xlabel('time (ns)')
    ax.set_ylabel('(E - E0) / |E0|')
    ax.set_title(f"ReversibleVerlet, {results['final_steps']:,} steps, "
                 f"total energy every {results['energy_every']} steps")
    fig.tight_layout()
    name = 'reversal_energy.png'
    fig.savefig(figures / name, dpi=110)
    plt.close(fig)
    return name


def _g(x):
    return f'{x:.2g}' if x else '0'


def render(results) -> str:
    s = results['system']
    vv = results['velocity_verlet']
    ours = results['reversible']
    en = results['energy']
    sh = ours['shape_at_turn']
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
    plots = results['plots']
    return f"""
Ar{s['atoms']} icosahedron thermalised at {s['temperature_K']:g} K (seed
{s['seed']}), {s['calculator']}, {s['timestep_fs']:g} fs, in a periodic cube
of edge {s['cell_edge']:.1f} Å: the cluster ({2 * s['cluster_radius_start']:.1f} Å
across at the start) does not interact with its images, and atoms that
evaporate stay nearby as vapour. (With free boundaries, an evaporated atom
flies off and asap3's neighbour list grows with the box enclosing all
atoms; the step cost grows without bound.) N steps forward, then N steps
with the time step negated; the error is the largest coordinate difference
from the start.
Both integrators start from the same state (the one ReversibleVerlet's
constructor put on its grid: position quantum {results['grid']['position_quantum']:.3g} Å,
momentum quantum {results['grid']['momentum_quantum']:.3g} amu Å / ASE time).

![reversal error](benchmarks/{plots[0]})

### Method

- VelocityVerlet: one forward run; at each N a copy of the atoms with a
  fresh asap3 calculator runs N steps back. The forward run keeps its own
  calculator, so it is one uninterrupted trajectory; the backward leg starts
  from a neighbour list built at the turning point rather than the one the
  forward run last used (a force difference of order 1e-15 eV/Å).
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
  {_g(ours['max_observed_noise'])} eV/Å.

### Results

| N | VelocityVerlet max \\|Δx\\| (Å) | VelocityVerlet max \\|Δp\\| (amu Å / ASE time) | ReversibleVerlet max \\|Δx\\| / \\|Δp\\| | ReversibleVerlet bitwise equal |
| --- | --- | --- | --- | --- |
""" + '\n'.join('| ' + ' | '.join(r) + ' |' for r in rows) + f"""

ReversibleVerlet returned to the start bit for bit at every N: {all_exact}.
VelocityVerlet after {vv_last['steps']:,} steps each way is
{_g(vv_last['position_error'])} Å from the start; the cluster's diameter at
the start is {_g(2 * s['cluster_radius_start'])} Å.

### Energy over the {results['final_steps']:,}-step run

![energy](benchmarks/{plots[1]})

Total energy of ReversibleVerlet's forward run, read every
{results['energy_every']:,} steps ({en['duration_ns']:.3g} ns), E0 =
{en['e0']:.6g} eV:

- largest |E - E0| / |E0|: {_g(en['max_relative_deviation'])} (first tenth
  of the run: {_g(en['max_relative_deviation_first_tenth'])}; last tenth:
  {_g(en['max_relative_deviation_last_tenth'])});
- mean E in the first and last tenth ({en['samples_per_tenth']} samples
  each): {en['mean_first_tenth']:.6g} and {en['mean_last_tenth']:.6g} eV,
  standard deviations {_g(en['std_first_tenth'])} and
  {_g(en['std_last_tenth'])} eV; the mean moved by
  {en['mean_shift_in_std']:.2g} first-tenth standard deviations;
- least-squares drift: {en['drift_eV_per_ns']:.2g} eV/ns.

After the {results['final_steps']:,} forward steps the centre of mass had
moved {sh['centre_displacement']:.3g} Å (the thermalised momenta carry a net
momentum) and {sh['isolated_atoms']} atoms had no neighbour within the
{AR_CUTOFF:g} Å cutoff (evaporated, a vapour in the periodic box).
"""
