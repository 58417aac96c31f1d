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
VelocityVerlet runs; they differ by force noise in the last bits, which is
the kind of error the curve measures anyway.  This costs N per point instead
of a whole new round trip.  The forward run then goes on to the final
length, for its energy only.

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
    # evaporates flies off, and asap3's neighbour list grows with the box
    # enclosing all atoms: in a trial run with free boundaries one atom left
    # after about 2.3e5 steps, and by 5e5 steps a step cost 13 times what
    # it did at the start, and more every step (and memory grew with it).
    # In the box the vapour stays near the cluster.
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


def velocity_verlet_curve(x0, p0, grid, dt, final, energy_every):
    twin = make_cluster()
    twin.set_positions(x0)
    twin.set_momenta(p0)
    forward = VelocityVerlet(twin, dt)
    points = []
    # The forward run goes on to the final length only for its energy, the
    # reference for ReversibleVerlet's: past the grid its round trips are
    # not worth their cost, the error having long reached its ceiling.
    energies = [(0, twin.get_total_energy())]
    backward_steps = 0
    tic = time.perf_counter()
    for stop in _stops(grid, final, energy_every):
        forward.run(stop - forward.nsteps)
        if stop % energy_every == 0:
            energies.append((stop, twin.get_total_energy()))
        if stop not in grid:
            continue
        back = twin.copy()
        back.calc = fresh_calculator()
        VelocityVerlet(back, -dt).run(stop)
        backward_steps += stop
        dx, dp = largest_difference(back, x0, p0)
        points.append({'steps': stop, 'position_error': dx,
                       'momentum_error': dp})
    seconds = time.perf_counter() - tic
    return {'points': points, 'seconds': seconds,
            'steps_run': final + backward_steps,
            'seconds_per_step': seconds / (final + backward_steps),
            'energy_steps': [n for n, _ in energies],
            'energies': [float(e) for _, e in energies],
            'shape_at_end': cluster_shape(twin, x0)}


def _stops(grid, final, energy_every):
    return sorted(set(grid) | {final}
                  | set(range(energy_every, final + 1, energy_every)))


def reversible_run(atoms, dyn, x0, p0, grid, final, energy_every):
    e0 = atoms.get_total_energy()
    energies = [(0, e0)]
    checkpoints = []
    steps_run = 0
    position = 0
    tic = time.perf_counter()
    for stop in _stops(grid, final, energy_every):
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
        'force_noise_bound': getattr(purity, 'force_noise', None),
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

    vv = velocity_verlet_curve(x0, p0, grid, dt, mode['final'],
                               mode['energy_every'])
    ours = reversible_run(atoms, dyn, x0, p0, grid, mode['final'],
                          mode['energy_every'])
    energy = {name: energy_summary(run['energy_steps'], run['energies'],
                                   TIMESTEP_FS)
              for name, run in (('reversible', ours), ('velocity_verlet', vv))}
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
    axes[0].axhline(2 * results['system']['cluster_radius_start'],
                    color='grey', ls=':', label='cluster diameter at start')
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
    fig, ax = plt.subplots(figsize=(7, 3.4))
    for key, label, color in (('velocity_verlet', 'VelocityVerlet', 'C3'),
                              ('reversible', 'ReversibleVerlet', 'C0')):
        run = results[key]
        e = np.asarray(run['energies'])
        t_ns = np.asarray(run['energy_steps']) * TIMESTEP_FS * 1e-6
        ax.plot(t_ns, (e - e[0]) / abs(e[0]), lw=0.8, color=color,
                label=label)
    ax.axhline(0, color='grey', lw=0.5)
    ax.set_xlabel('time (ns)')
    ax.set_ylabel('(E - E0) / |E0|')
    ax.legend(loc='best')
    ax.set_title(f"{results['final_steps']:,} steps forward, total energy "
                 f"every {results['energy_every']} steps")
    fig.tight_layout()
    name = 'reversal_energy.png'
    fig.savefig(figures / name, dpi=110)
    plt.close(fig)
    return name


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
            f'of the run is {n} samples.\n\n' + common.markdown_table(
                ['integrator', 'max \\|E-E0\\|/\\|E0\\|',
                 'same, first tenth', 'same, last tenth',
                 'mean(last tenth) - mean(first tenth) (eV)',
                 'std first / last tenth (eV)',
                 'mean shift / first-tenth std', 'fitted drift (eV/ns)'],
                rows))


def render(results) -> str:
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
    plots = results['plots']
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

![reversal error](benchmarks/{plots[0]})

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

![energy](benchmarks/{plots[1]})

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
({vsh['isolated_atoms']}) atoms had no neighbour within the {AR_CUTOFF:g} Å
cutoff: evaporated, a vapour in the periodic box.
"""
