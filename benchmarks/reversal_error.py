"""Reversal error against the number of steps, and a 10^6-step round trip
(the method: docs/benchmarks.md, "Reversal error against steps")."""

from __future__ import annotations

import common  # noqa: F401  (first: pins BLAS threads before numpy)

import time

import numpy as np
import systems
from ase import units
from ase.md.verlet import VelocityVerlet

from ase_reversible import ReversibleVerlet
from ase_reversible.app.systems import AR_RC, argon_cluster

ATOMS, SHELLS, TEMPERATURE_K, TIMESTEP_FS, SEED = 147, 4, 120.0, 5.0, 0

# (checkpoints, final length) per mode.  The grid doubles from 125 so
# that it passes through N = 1000, 4000 and 16000.
QUICK = dict(grid=[125 * 2 ** k for k in range(7)], final=8000)  # ... 8000
FULL = dict(grid=[125 * 2 ** k for k in range(11)],              # ... 128000
            final=1_000_000)


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


def velocity_verlet_curve(x0, p0, grid, dt, final):
    twin = make_cluster()
    twin.set_positions(x0)
    twin.set_momenta(p0)
    forward = VelocityVerlet(twin, dt)
    points = []
    # The forward run goes on to the final length only for its time per
    # step over ReversibleVerlet's length: past the grid its round trips
    # are not worth their cost, the error having long reached its ceiling.
    backward_steps = 0
    tic = time.perf_counter()
    for stop in sorted(set(grid) | {final}):
        forward.run(stop - forward.nsteps)
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
            'seconds_per_step': seconds / (final + backward_steps)}


def reversible_run(atoms, dyn, x0, p0, grid, final):
    checkpoints = []
    steps_run = 0
    position = 0
    tic = time.perf_counter()
    for stop in sorted(set(grid) | {final}):
        dyn.run(stop - position)
        steps_run += stop - position
        position = stop
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
        'seconds': seconds, 'steps_run': steps_run,
        'seconds_per_step': seconds / steps_run,
        'force_purity': purity.mode,
        'clean_recomputations': getattr(purity, 'clean_recomputations', None),
        'max_observed_noise': getattr(purity, 'max_observed_noise', None),
        'force_noise_bound': getattr(purity, 'force_noise', None),
    }


def run(quick: bool):
    mode = QUICK if quick else FULL
    dt = TIMESTEP_FS * units.fs
    atoms = make_cluster()
    dyn = ReversibleVerlet(atoms, dt)
    x0, p0 = atoms.get_positions(), atoms.get_momenta()
    grid = [n for n in mode['grid'] if n <= mode['final']]
    radius0 = float(np.linalg.norm(x0 - x0.mean(axis=0), axis=1).max())

    vv = velocity_verlet_curve(x0, p0, grid, dt, mode['final'])
    ours = reversible_run(atoms, dyn, x0, p0, grid, mode['final'])
    results = {
        'system': {'atoms': ATOMS, 'temperature_K': TEMPERATURE_K,
                   'timestep_fs': TIMESTEP_FS, 'seed': SEED,
                   'calculator': f'asap3 LennardJones (rCut {AR_RC:g} Å, '
                                 'modified)',
                   'cluster_radius_start': radius0,
                   'cell_edge': float(atoms.cell.lengths()[0])},
        'grid': {'position_quantum': dyn.grid.position_quantum,
                 'momentum_quantum': dyn.grid.momentum_quantum},
        'final_steps': mode['final'],
        'velocity_verlet': vv,
        'reversible': ours,
    }
    return results
