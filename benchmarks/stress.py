"""Numerical stability: time steps past the stability limit, evaporating
clusters, close contacts, diffusion over many cells (the scenes:
docs/benchmarks.md).  Energies against the initial kinetic energy K0."""

from __future__ import annotations

import common  # noqa: F401  (first: pins BLAS threads before numpy)

import inspect
import json
import time
import warnings

import numpy as np
from ase import units
from ase.cluster import Icosahedron
from ase.md.verlet import VelocityVerlet
from systems import (CALCULATORS, CU_BOND, argon_fluid, copper_bulk_contact,
                     pair)

from ase_reversible import (AnchorMovedWarning, ReversibilityError,
                            ReversibleVerlet)
# Not public: the defaults of the ranges and of the energy check's
# tolerance, recorded beside the results they explain.
from ase_reversible.core import quanta
from ase_reversible.md import hamiltonian
from ase_reversible.app.systems import (AR_RC, AR_SIGMA, argon_cluster,
                                        copper_bulk)

#: Time step of every scene but the sweep, fs.
DT_FS = 5


# -- running ------------------------------------------------------------------

def kinetic_energy(atoms):
    p_nc = atoms.get_momenta()
    return float((p_nc**2 / atoms.get_masses()[:, None]).sum() / 2)


def forward_and_back(atoms, dt_fs, steps, **kwargs):
    """ReversibleVerlet ``steps`` forward (or until it raises), then back.

    Returns the total energy after the constructor and after every
    committed step, the state at the turn, the error if one was raised,
    and whether the run back reached the constructor's state bit for bit.
    """
    dyn = ReversibleVerlet(atoms, dt_fs * units.fs, **kwargs)
    x0_nc, p0_nc = atoms.get_positions(), atoms.get_momenta()
    energies = []
    dyn.attach(lambda: energies.append(atoms.get_total_energy()))
    error = None
    tic = time.perf_counter()
    # Blown-up runs make the calculators overflow in float64; the
    # integrator's range checks are what is measured here.
    with np.errstate(all='ignore'):
        try:
            dyn.run(steps)
        except ReversibilityError as err:
            error = {'type': type(err).__name__, 'step': dyn.nsteps + 1,
                     'message': str(err)}
    seconds = time.perf_counter() - tic
    done = dyn.nsteps
    x_turn, p_turn = atoms.get_positions(), atoms.get_momenta()
    dyn.observers.clear()
    dyn.reverse()
    with warnings.catch_warnings():
        # Re-anchoring on the way back would hide a corrupted state.
        warnings.simplefilter('error', AnchorMovedWarning)
        dyn.run(done)
    exact = bool(np.array_equal(atoms.positions, x0_nc)
                 and np.array_equal(atoms.get_momenta(), p0_nc))
    return {'dyn': dyn, 'steps_done': done, 'error': error,
            'energies': np.array(energies), 'x0': x0_nc, 'x_turn': x_turn,
            'p_turn': p_turn, 'exact': exact, 'seconds': seconds}


def velocity_verlet(atoms, dt_fs, steps):
    dyn = VelocityVerlet(atoms, dt_fs * units.fs)
    energies = []
    dyn.attach(lambda: energies.append(atoms.get_total_energy()))
    error = None
    with np.errstate(all='ignore'):
        try:
            dyn.run(steps)
        except Exception as err:  # whatever ASE or the calculator raises
            error = {'type': type(err).__name__, 'step': dyn.nsteps + 1,
                     'message': str(err)}
    return {'steps_done': dyn.nsteps, 'error': error,
            'energies': np.array(energies),
            'x_max': float(np.abs(atoms.positions).max()),
            'p_max': float(np.abs(atoms.get_momenta()).max())}


def energy_summary(energies, scale):
    """Max ``|E - E0| / scale``, and the first step where it exceeds 1 or
    is not finite (``None`` if never)."""
    with np.errstate(all='ignore'):
        error = np.abs(energies - energies[0]) / scale
    error[~np.isfinite(error)] = np.inf
    bad = np.flatnonzero(error > 1)
    return (float(error.max()),
            int(bad[0]) if len(bad) else None)


def grid_use(run):
    grid = run['dyn'].grid
    return {'position_range': grid.position_range,
            'momentum_range': grid.momentum_range,
            'x_max': float(np.abs(run['x_turn']).max()),
            'p_max': float(np.abs(run['p_turn']).max())}


# -- (a) time-step sweep -----------------------------------------------------

def sweep_systems(quick):
    shells, steps_ar = (2, 200) if quick else (3, 1000)
    return [
        {'name': f'Ar{len(Icosahedron("Ar", shells))} cluster, 40 K',
         'calculator': 'ASE LJ', 'steps': steps_ar,
         'make': lambda: argon_cluster(shells, 40),
         'dts_fs': ([5, 50, 120, 150, 200, 400, 800] if quick else
                    [2, 5, 10, 20, 50, 80, 100, 120, 150, 200, 400, 800])},
        {'name': 'Cu108 bulk, 300 K', 'calculator': 'asap3 EMT',
         'steps': 300 if quick else 1000,
         'make': lambda: copper_bulk((3, 3, 3), 300),
         'dts_fs': ([2, 5, 10, 20, 25, 30, 40, 100, 800] if quick else
                    [1, 2, 5, 10, 15, 20, 25, 30, 40, 60, 100, 200, 800])},
    ]


def sweep(system):
    rows = []
    for dt_fs in system['dts_fs']:
        atoms = system['make']()
        atoms.calc = CALCULATORS[system['calculator']]()
        k0 = kinetic_energy(atoms)
        ours = forward_and_back(atoms, dt_fs, system['steps'])
        worst, first_bad = energy_summary(ours['energies'], k0)
        # The energy check's own tolerance (max of K0 and the 100 K
        # floor): what it promises to stop within two steps of.
        tolerance = ours['dyn'].engine.invariant.limit
        beyond = (None if tolerance is None else
                  energy_summary(ours['energies'], tolerance)[1])

        def steps_from(first):
            """Committed steps from ``first`` (None: never) to the last."""
            return 0 if first is None else ours['steps_done'] - first + 1

        row = {'dt_fs': dt_fs, 'k0': k0, 'tolerance': tolerance,
               'first_beyond_tolerance_step': beyond,
               'steps_beyond_tolerance': steps_from(beyond),
               'steps_done': ours['steps_done'], 'error': ours['error'],
               'exact': ours['exact'], 'max_energy_error': worst,
               'first_garbage_step': first_bad,
               'silent_steps': steps_from(first_bad), **grid_use(ours)}
        atoms = system['make']()
        atoms.calc = CALCULATORS[system['calculator']]()
        vv = velocity_verlet(atoms, dt_fs, system['steps'])
        vv_worst, vv_first_bad = energy_summary(vv['energies'], k0)
        row['vv'] = {'steps_done': vv['steps_done'], 'error': vv['error'],
                     'max_energy_error': vv_worst,
                     'first_garbage_step': vv_first_bad,
                     'non_finite': not np.all(np.isfinite(vv['energies'])),
                     'x_max': vv['x_max'], 'p_max': vv['p_max']}
        rows.append(row)
    return {key: system[key] for key in ('name', 'calculator', 'steps')} | {
        'rows': rows}


# -- (b) evaporation ----------------------------------------------------------

def evaporation_cases(quick):
    cases = [('Ar13', 2, 1000, 1000 if quick else 8000, {}),
             ('Ar13', 2, 1000, 4000,
              {'position_quantum': 2.0**-48 if quick else 2.0**-47})]
    if not quick:
        cases.insert(1, ('Ar55', 3, 500, 2000, {}))
    return cases


def nearest_neighbour_distances(x_nc):
    d = np.linalg.norm(x_nc[:, None] - x_nc[None], axis=-1)
    np.fill_diagonal(d, np.inf)
    return d.min(axis=1)


def scene_row(system, atoms, steps, kwargs, extra):
    """A run out and back under ASE LJ: the fields every scene records,
    and those of ``extra(run)``."""
    atoms.calc = CALCULATORS['ASE LJ']()
    k0 = kinetic_energy(atoms)
    run = forward_and_back(atoms, DT_FS, steps, **kwargs)
    return {'system': system, 'steps': steps, 'kwargs': kwargs,
            'steps_done': run['steps_done'], 'error': run['error'],
            'exact': run['exact'],
            'max_energy_error': energy_summary(run['energies'], k0)[0],
            'seconds': run['seconds'], **grid_use(run), **extra(run)}


def evaporation(quick):
    def shape(run):
        centre = run['x0'].mean(axis=0)
        return {'evaporated': int((nearest_neighbour_distances(run['x_turn'])
                                   > AR_RC).sum()),
                'n_atoms': len(run['x0']),
                'furthest_from_centre': float(np.linalg.norm(
                    run['x_turn'] - centre, axis=1).max())}
    return [scene_row(f'{name}, {temperature} K',
                      argon_cluster(shells, temperature), steps, kwargs, shape)
            for name, shells, temperature, steps, kwargs
            in evaporation_cases(quick)]


# -- (c) close contacts ------------------------------------------------------

def contact_cases(quick):
    cases = [('Ar2', 'ASE LJ', f, lambda f: pair('Ar', f * AR_SIGMA), 200)
             for f in (0.7, 0.6, 0.5, 0.45, 0.3, 0.1)]
    cases += [('Cu2', 'ASE EMT', f, lambda f: pair('Cu', f * CU_BOND), 200)
              for f in (0.5, 0.1, 0.01)]
    cases += [('Cu108 bulk', calc, f, copper_bulk_contact, steps)
              for calc, steps in (('asap3 EMT', 500),
                                  ('ASE EMT', 12 if quick else 200))
              for f in (0.3, 0.1)]
    return cases


def contacts(quick):
    rows = []
    for system, calc, fraction, make, steps in contact_cases(quick):
        atoms = make(fraction)
        atoms.calc = CALCULATORS[calc]()
        f_max = float(np.abs(atoms.get_forces()).max())
        run = forward_and_back(atoms, DT_FS, steps)
        energies = run['energies']
        _, first_bad = energy_summary(energies, abs(energies[0]))
        atoms = make(fraction)
        atoms.calc = CALCULATORS[calc]()
        vv = velocity_verlet(atoms, DT_FS, steps)
        rows.append({
            'system': system, 'calculator': calc, 'fraction': fraction,
            'unit': 'σ' if 'LJ' in calc else 'Cu bond', 'steps': steps,
            'f_max': f_max, 'e0': float(energies[0]),
            'steps_done': run['steps_done'], 'error': run['error'],
            'exact': run['exact'], 'first_garbage_step': first_bad,
            'max_energy_change': float(np.abs(energies - energies[0]).max()),
            'vv_max_energy_change': float(np.nanmax(
                np.abs(vv['energies'] - vv['energies'][0]))),
            **grid_use(run)})
    return rows


# -- (d) periodic diffusion --------------------------------------------------

def diffusion_cases(quick):
    cases = [('Ar4 gas', 4, 10.0, 3000, 1000 if quick else 10000, {}),
             ('Ar4 gas', 4, 10.0, 3000, 3000,
              {'position_quantum': 2.0**-48})]
    if not quick:
        cases.insert(1, ('Ar32 hot fluid', 32, 12.0, 2000, 3000, {}))
    return cases


def diffusion(quick):
    def cells(length):
        def moved(run):
            d = np.linalg.norm(run['x_turn'] - run['x0'], axis=1) / length
            return {'cell_length': length, 'max_cells': float(d.max()),
                    'mean_cells': float(d.mean())}
        return moved
    return [scene_row(f'{name}, {length:g} Å cell, {temperature} K',
                      argon_fluid(n, length, temperature), steps, kwargs,
                      cells(length))
            for name, n, length, temperature, steps, kwargs
            in diffusion_cases(quick)]


# -- section interface ------------------------------------------------------

def _plain(value):
    """JSON-ready copy: numpy scalars to Python, no arrays."""
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float) and not np.isfinite(value):
        return repr(value)  # JSON has no inf or nan
    return value


def run(quick):
    sweeps = [sweep(system) for system in sweep_systems(quick)]
    results = {
        'settings': {
            'dt_fs': DT_FS, 'ar_sigma': AR_SIGMA, 'cu_bond': CU_BOND,
            'momentum_room': quanta.MOMENTUM_ROOM,
            'momentum_temperature_floor':
                quanta.MOMENTUM_TEMPERATURE_FLOOR,
            'position_room': quanta.POSITION_ROOM,
            'energy_check_interval': inspect.signature(
                ReversibleVerlet).parameters['energy_check'].default,
            'energy_tolerance_temperature':
                hamiltonian.ENERGY_TOLERANCE_TEMPERATURE},
        'sweeps': sweeps, 'evaporation': evaporation(quick),
        'contacts': contacts(quick), 'diffusion': diffusion(quick)}
    return json.loads(json.dumps(_plain(results)))

