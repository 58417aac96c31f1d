"""Numerical stability: blow-ups, evaporation, close contacts, diffusion.

Scenes (every ReversibleVerlet run uses the default quanta and
``scheme='velocity'`` unless a row says otherwise):

(a) Time-step sweep, from a usual step far past the stability limit, for
    a free argon cluster (ASE LennardJones: 'sorted' force purity, a fine
    momentum quantum) and periodic copper (asap3 EMT: 'guarded' purity,
    whose momentum quantum is much coarser and its range much larger).
    ReversibleVerlet and ASE's VelocityVerlet run the same atoms; for
    ReversibleVerlet a run that stops with an error is run back from where
    it stopped.
(b) Hot argon clusters evaporating (ASE LennardJones).
(c) Close contacts: two atoms, or one atom in bulk copper, pushed to a
    fraction of the bond length, so forces are huge.
(d) Hot argon fluid and gas in small periodic cells (ASE LennardJones,
    whose neighbour list handles a cutoff beyond half the cell), followed
    over many cell lengths without wrapping.
(e) asap3 with atoms far apart in a non-periodic cell, in a subprocess
    with a memory limit: what an evaporating or blown-up cluster would hand
    to asap3 inside ReversibleVerlet's default position range.

Energies are compared with the initial kinetic energy ``K0``: a run whose
``|E - E0|`` exceeds ``K0`` has an energy error larger than all the
thermal energy it started with, which is garbage however it is judged.
"""

from __future__ import annotations

import common  # noqa: F401  (first: pins BLAS threads before numpy)

import json
import subprocess
import sys
import textwrap
import time
import warnings

import asap3
import numpy as np
from ase import Atoms, units
from ase.build import bulk
from ase.calculators.emt import EMT
from ase.calculators.lj import LennardJones
from ase.cluster import Icosahedron
from ase.md.verlet import VelocityVerlet

from ase_reversible import verlet
from ase_reversible import (AnchorMovedWarning, ReversibilityError,
                            ReversibleVerlet)
from ase_reversible import fixedpoint

TITLE = 'Numerical stability under stress'

AR_EPSILON, AR_SIGMA, AR_RC, AR_LATTICE = 0.0104, 3.4, 8.5, 5.26
CU_LATTICE = 3.61  # ase.build.bulk's value for Cu
CU_BOND = CU_LATTICE / np.sqrt(2)

CALCULATORS = {
    'ASE LJ': lambda: LennardJones(sigma=AR_SIGMA, epsilon=AR_EPSILON,
                                   rc=AR_RC),
    'asap3 LJ': lambda: asap3.LennardJones([18], [AR_EPSILON], [AR_SIGMA],
                                           rCut=AR_RC, modified=True),
    'ASE EMT': EMT,
    'asap3 EMT': asap3.EMT,
}

#: Time step of every scene but the sweep, fs.
DT_FS = 5

#: Memory limit of the subprocess of scene (e): more than asap3 needs for
#: atoms 1000 Å apart, small enough to be harmless on a shared machine.
SUBPROCESS_MEMORY = 3 * 2**30


# -- systems ------------------------------------------------------------------

def argon_cluster(shells, temperature_K, seed=0):
    atoms = Icosahedron('Ar', shells, latticeconstant=AR_LATTICE)
    atoms.center(vacuum=10.0)  # asap3 wants a cell even without pbc
    return common.thermalised(atoms, temperature_K, seed)


def copper_bulk(size, temperature_K, seed=0):
    atoms = bulk('Cu', cubic=True) * size
    atoms.rattle(0.05, seed=seed)
    return common.thermalised(atoms, temperature_K, seed)


def argon_fluid(n_atoms, cell_length, temperature_K, seed=0):
    """``n_atoms`` on a simple cubic lattice in a periodic cube."""
    k = int(np.ceil(n_atoms ** (1 / 3)))
    sites = (np.indices((k, k, k)).reshape(3, -1).T[:n_atoms] + 0.5) / k
    atoms = Atoms(f'Ar{n_atoms}', scaled_positions=sites,
                  cell=[cell_length] * 3, pbc=True)
    return common.thermalised(atoms, temperature_K, seed)


def pair(symbol, gap):
    atoms = Atoms(symbol * 2, positions=[(0, 0, 0), (gap, 0, 0)])
    atoms.center(vacuum=10.0)
    return atoms


def copper_bulk_contact(fraction):
    """Perfect Cu bulk (108 atoms) with atom 0 moved towards a neighbour
    until they are ``fraction`` of the bond length apart."""
    atoms = bulk('Cu', cubic=True) * (3, 3, 3)
    vectors = atoms.get_distances(0, range(1, len(atoms)), mic=True,
                                  vector=True)
    nearest = vectors[np.argmin(np.linalg.norm(vectors, axis=1))]
    atoms.positions[0] += (1 - fraction) * nearest
    return atoms


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
        row = {'dt_fs': dt_fs, 'k0': k0,
               'steps_done': ours['steps_done'], 'error': ours['error'],
               'exact': ours['exact'], 'max_energy_error': worst,
               'first_garbage_step': first_bad,
               'energy_trace': (np.abs(ours['energies'] - ours['energies'][0])
                                / k0).tolist(),
               **grid_use(ours)}
        atoms = system['make']()
        atoms.calc = CALCULATORS[system['calculator']]()
        vv = velocity_verlet(atoms, dt_fs, system['steps'])
        vv_worst, vv_first_bad = energy_summary(vv['energies'], k0)
        row['vv'] = {'steps_done': vv['steps_done'], 'error': vv['error'],
                     'max_energy_error': vv_worst,
                     'first_garbage_step': vv_first_bad,
                     'non_finite': not np.all(np.isfinite(vv['energies'])),
                     'x_max': vv['x_max'], 'p_max': vv['p_max'],
                     'energy_trace': [
                         x if np.isfinite(x) else None for x in
                         (np.abs(vv['energies'] - vv['energies'][0]) / k0)]}
        rows.append(row)
    return {key: system[key] for key in ('name', 'calculator', 'steps')} | {
        'rows': rows}


def plot_sweep(sweeps, figures):
    plt = common.pyplot()
    fig, axes = plt.subplots(1, len(sweeps), figsize=(6 * len(sweeps), 4.5))
    for ax, result in zip(np.atleast_1d(axes), sweeps):
        rows = result['rows']
        dts = [r['dt_fs'] for r in rows]
        # Runs stopped before their first step have no error to show:
        # they sit on the floor of the plot, labelled with the step.
        ours = [max(r['max_energy_error'], PLOT_FLOOR) for r in rows]
        vv = [min(max(r['vv']['max_energy_error'], PLOT_FLOOR), 1e30)
              for r in rows]
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
    fig.savefig(figures / 'stress_dt_sweep.png', dpi=110)
    plt.close(fig)


PLOT_FLOOR = 1e-6


def silent_window(row):
    """Steps ReversibleVerlet took with |E - E0| > K0 before it stopped
    (or finished)."""
    if row['first_garbage_step'] is None:
        return 0
    return row['steps_done'] - row['first_garbage_step'] + 1


def traced_row(result):
    late = [r for r in result['rows'] if r['first_garbage_step'] is not None
            and r['first_garbage_step'] > 1]
    return max(late or result['rows'], key=silent_window)


def plot_traces(sweeps, figures):
    """Energy error step by step in the run of each system that started
    sane and then spent the most steps with |E - E0| > K0."""
    plt = common.pyplot()
    fig, axes = plt.subplots(1, len(sweeps), figsize=(6 * len(sweeps), 4))
    for ax, result in zip(np.atleast_1d(axes), sweeps):
        row = traced_row(result)
        result['traced_dt_fs'] = row['dt_fs']
        vv = np.array([np.nan if x is None else x
                       for x in row['vv']['energy_trace']])
        ax.plot(np.maximum(vv, PLOT_FLOOR), color='0.6', lw=4, alpha=0.6,
                label='VelocityVerlet')
        ax.plot(np.maximum(row['energy_trace'], PLOT_FLOOR), color='C0',
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
    fig.savefig(figures / 'stress_blowup_traces.png', dpi=110)
    plt.close(fig)


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


def evaporation(quick):
    rows = []
    for name, shells, temperature, steps, kwargs in evaporation_cases(quick):
        atoms = argon_cluster(shells, temperature)
        atoms.calc = CALCULATORS['ASE LJ']()
        k0 = kinetic_energy(atoms)
        run = forward_and_back(atoms, DT_FS, steps, **kwargs)
        centre = run['x0'].mean(axis=0)
        worst, _ = energy_summary(run['energies'], k0)
        rows.append({
            'system': f'{name}, {temperature} K', 'steps': steps,
            'kwargs': kwargs, 'steps_done': run['steps_done'],
            'error': run['error'], 'exact': run['exact'],
            'evaporated': int((nearest_neighbour_distances(run['x_turn'])
                               > AR_RC).sum()),
            'n_atoms': len(atoms),
            'furthest_from_centre': float(np.linalg.norm(
                run['x_turn'] - centre, axis=1).max()),
            'max_energy_error': worst, 'seconds': run['seconds'],
            **grid_use(run)})
    return rows


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
    rows = []
    for name, n, length, temperature, steps, kwargs in diffusion_cases(quick):
        atoms = argon_fluid(n, length, temperature)
        atoms.calc = CALCULATORS['ASE LJ']()
        k0 = kinetic_energy(atoms)
        run = forward_and_back(atoms, DT_FS, steps, **kwargs)
        moved = np.linalg.norm(run['x_turn'] - run['x0'], axis=1) / length
        worst, _ = energy_summary(run['energies'], k0)
        rows.append({
            'system': f'{name}, {length:g} Å cell, {temperature} K',
            'cell_length': length, 'steps': steps, 'kwargs': kwargs,
            'steps_done': run['steps_done'], 'error': run['error'],
            'exact': run['exact'], 'max_cells': float(moved.max()),
            'mean_cells': float(moved.mean()), 'max_energy_error': worst,
            'seconds': run['seconds'], **grid_use(run)})
    return rows


# -- (e) asap3 with atoms far apart -----------------------------------------

FAR_APART = textwrap.dedent('''
    import resource, sys, time
    import numpy as np
    import asap3
    from ase.calculators.lj import LennardJones
    from ase.cluster import Icosahedron
    resource.setrlimit(resource.RLIMIT_AS, ({limit}, {limit}))
    atoms = Icosahedron('Ar', 2, latticeconstant={lattice})
    atoms.center(vacuum=10.0)
    if '{calc}' == 'asap3 LJ':
        atoms.calc = asap3.LennardJones([18], [{eps}], [{sigma}],
                                        rCut={rc}, modified=True)
    else:
        atoms.calc = LennardJones(sigma={sigma}, epsilon={eps}, rc={rc})
    atoms.get_forces()
    atoms.positions[1] += {distance}
    atoms.positions[2] -= {distance}
    tic = time.perf_counter()
    atoms.get_forces()
    print(time.perf_counter() - tic,
          resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024)
''')


def far_apart(quick):
    """Two atoms of Ar13 moved by ±d along (1, 1, 1): one force call."""
    atoms = argon_cluster(2, 40)
    atoms.calc = CALCULATORS['ASE LJ']()
    dyn = ReversibleVerlet(atoms, DT_FS * units.fs)
    default_range = dyn.grid.position_range
    cases = [('asap3 LJ', d) for d in ((100, 3000) if quick
                                       else (100, 300, 1000, 2000, 3000))]
    cases.append(('ASE LJ', 3000))
    rows = []
    for calc, distance in cases:
        code = FAR_APART.format(limit=SUBPROCESS_MEMORY, lattice=AR_LATTICE,
                                calc=calc, eps=AR_EPSILON, sigma=AR_SIGMA,
                                rc=AR_RC, distance=distance)
        done = subprocess.run([sys.executable, '-c', code],
                              capture_output=True, text=True, timeout=300)
        x_nc = atoms.positions.copy()
        x_nc[1] += distance
        x_nc[2] -= distance
        row = {'calculator': calc, 'distance': distance,
               'spread': float(np.linalg.norm(x_nc[1] - x_nc[2])),
               'x_max': float(np.abs(x_nc).max()),
               'returncode': done.returncode}
        if done.returncode == 0:
            seconds, rss = map(float, done.stdout.split())
            row |= {'seconds': seconds, 'max_rss_mb': rss}
        else:
            row['stderr'] = [line.strip() for line in
                             done.stderr.strip().splitlines()[-1:]]
        rows.append(row)
    return {'default_position_range': default_range,
            'memory_limit_gib': SUBPROCESS_MEMORY / 2**30, 'rows': rows}


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


def run(quick, figures):
    sweeps = [sweep(system) for system in sweep_systems(quick)]
    plot_sweep(sweeps, figures)
    plot_traces(sweeps, figures)
    for result in sweeps:  # plotted; too long for the stored results
        for row in result['rows']:
            del row['energy_trace'], row['vv']['energy_trace']
    results = {'sweeps': sweeps, 'evaporation': evaporation(quick),
               'contacts': contacts(quick), 'diffusion': diffusion(quick),
               'far_apart': far_apart(quick)}
    return json.loads(json.dumps(_plain(results)))


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
    exponent = np.frexp(kwargs['position_quantum'])[1] - 1
    return f', position_quantum = 2^{exponent} Å'


def render(results):
    out = [
        'Each scene runs ReversibleVerlet forward, then reverses it and runs '
        'back as many steps as it completed (all of them, or those before '
        'an error), and checks that positions and momenta are those right '
        'after the constructor, bit for bit ("exact"). Energy errors are '
        '`max |E - E0|` over the committed steps divided by the initial '
        'kinetic energy `K0`: above 1 the error exceeds all the thermal '
        f'energy the run started with. Time step {DT_FS} fs unless a table '
        'says otherwise; default quanta unless a row gives '
        '`position_quantum`.',
        '']
    out += _render_sweep(results['sweeps'])
    out += _render_evaporation(results['evaporation'])
    out += _render_contacts(results['contacts'])
    out += _render_diffusion(results['diffusion'])
    out += _render_far_apart(results['far_apart'])
    return '\n'.join(out)


def _render_sweep(sweeps):
    out = ['### Time step far past the stability limit', '',
           '![energy error against time step](benchmarks/stress_dt_sweep.png)',
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
                silent_window(r), _yes(r['exact']),
                f'{r["p_max"]:.3g} / {r["momentum_range"]:.3g}',
                f'{_float(vv["max_energy_error"]):.3g}'
                + (' (non-finite)' if vv['non_finite'] else ''),
                '-' if vv['first_garbage_step'] is None
                else vv['first_garbage_step'],
                f'{_float(vv["x_max"]):.3g}'])
        out += [common.markdown_table(
            ['dt (fs)', 'ReversibleVerlet', 'max \\|ΔE\\|/K0',
             'first step \\|ΔE\\| > K0', 'steps with \\|ΔE\\| > K0',
             'exact', 'max \\|p\\| / range at the turn',
             'VV max \\|ΔE\\|/K0', 'VV first step \\|ΔE\\| > K0',
             'VV max \\|x\\| (Å)'], table), '']
        sane = []
        for r in rows:
            if r['first_garbage_step'] is not None or r['error'] is not None:
                break
            sane.append(r['dt_fs'])
        stopped = [r for r in rows if r['error'] is not None]
        silent = [r for r in rows if silent_window(r) > 0]
        text = []
        if sane:
            text.append(f'ReversibleVerlet completed every run with |ΔE| < '
                        f'K0 up to {sane[-1]:g} fs.')
        if stopped:
            kinds = sorted({f'{r["error"]["type"]}: {_what(r["error"])}'
                            for r in stopped})
            text.append(f'It stopped at '
                        + ', '.join(f'{r["dt_fs"]:g}' for r in stopped)
                        + ' fs (' + '; '.join(kinds) + ').')
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
                    f'{r["dt_fs"]:g} fs: {_steps(silent_window(r))} from step '
                    f'{r["first_garbage_step"]}, up to '
                    f'{_float(r["max_energy_error"]):.3g} K0, then '
                    + ('finished' if r['error'] is None else
                       f'stopped at step {r["error"]["step"]}')
                    for r in silent) + '.')
        out += [' '.join(text), '']
    out += ['![energy error step by step in the longest silent window]'
            '(benchmarks/stress_blowup_traces.png)', '',
            'Two detectors stop a blow-up. A step is refused when a momentum '
            'or position (or its increment) would leave the fixed-point '
            'range, which by default is '
            f'{fixedpoint.MOMENTUM_ROOM:g} times the larger of the initial '
            'momenta and the thermal momentum at '
            f'{fixedpoint.MOMENTUM_TEMPERATURE_FLOOR:g} K, and '
            f'{fixedpoint.POSITION_ROOM:g} times the system size; with the '
            'guarded force purity (asap3) the momentum quantum is coarser and '
            'the momentum range much wider (column "max |p| / range"). And '
            'the energy check compares the total energy with its start at '
            'steps 1, 2, 4, 8 and then every '
            f'{verlet.ENERGY_CHECK_INTERVAL} steps, against the larger of the '
            'initial kinetic energy and that of the atoms at '
            f'{verlet.ENERGY_TOLERANCE_TEMPERATURE:g} K; energy growth inside '
            'the ranges goes unnoticed only between two checks.', '']
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
    out += [common.markdown_table(
        ['system', 'ReversibleVerlet', 'evaporated', 'furthest from the '
         'centre (Å)', 'max \\|x\\| / position range (Å)',
         'max \\|ΔE\\|/K0', 'exact'], table), '']
    return out


def _render_contacts(rows):
    out = ['### Close contacts', '',
           'Two atoms at rest, or atom 0 of perfect Cu bulk moved towards its '
           'nearest neighbour, at the given fraction of σ '
           f'({AR_SIGMA} Å) or of the Cu bond ({CU_BOND:.3f} Å). ΔE is the '
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
    out += [common.markdown_table(
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
            f'{len(garbage)} ran on with |ΔE| > |E0|: the {DT_FS} fs step '
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
    out += [common.markdown_table(
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
    out += [common.markdown_table(['calculator', 'd (Å)',
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
