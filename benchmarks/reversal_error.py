"""Reversal error against the number of steps, and a 10^6-step round trip
(the method: docs/benchmarks.md, "Reversal error against steps")."""

from __future__ import annotations

import common  # noqa: F401  (first: pins BLAS threads before numpy)

import time

import numpy as np
import systems
from ase import units
from ase.geometry import get_distances
from ase.md.verlet import VelocityVerlet

from ase_reversible import ReversibleVerlet
from ase_reversible.app.systems import AR_RC, argon_cluster

ATOMS, SHELLS, TEMPERATURE_K, TIMESTEP_FS, SEED = 147, 4, 120.0, 5.0, 0

# (checkpoints, final length, energy interval) per mode.  The grid doubles
# from 125 so that it passes through N = 1000, 4000 and 16000.
QUICK = dict(grid=[125 * 2 ** k for k in range(7)],          # ... 8000
             final=8000, energy_every=100)
FULL = dict(grid=[125 * 2 ** k for k in range(11)],          # ... 128000
            final=1_000_000, energy_every=1000)


def make_cluster():
    atoms = argon_cluster(SHELLS, TEMPERATURE_K, SEED)
    assert len(atoms) == ATOMS
    # Periodic, in a box the cluster cannot see its images through (edge
    # minus cluster size > cutoff).  With free boundaries an atom that
    # evaporates flies off, and asap3's neighbour list grows with the box
    # enclosing all atoms: in a trial run with free boundaries one atom left
    # after about 2.3e5 steps, and by 5e5 steps a step cost 13 times what
    # it did at the start, and more every step (and memory grew with it).
    # In the box the vapour stays near the cluster.
    atoms.pbc = True
    atoms.calc = fresh_calculator()
    return atoms


#: A new asap3 LennardJones for argon on every call.
fresh_calculator = systems.asap3_argon_lj()


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
        'isolated_atoms': int(np.sum(distances.min(axis=1) > AR_RC)),
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
        'mean_first_tenth': float(first.mean()), 'std_first_tenth': spread,
        'mean_last_tenth': float(last.mean()),
        'samples_per_tenth': int(tenth),
        'mean_shift_in_std': float((last.mean() - first.mean()) / spread),
        'drift_eV_per_ns': slope,
        'duration_ns': float(t_ns[-1]),
    }


def run(quick: bool):
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
                   'calculator': f'asap3 LennardJones (rCut {AR_RC:g} Å, '
                                 'modified)',
                   'cutoff': AR_RC,
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
    return results
