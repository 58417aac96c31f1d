"""One LAMMPS job of tests/test_lammps_nvt.py, on every rank of ``mpiexec``.

``python lammps_nvt_worker.py JOB OUT.npz [key=value ...]``: builds a
system, runs the job with :class:`ReversibleLammpsNose` and has rank 0 save
the gathered states (ids, unwrapped positions, real velocities, virtual
velocities recovered from them and ``s``, and ``s``, ``pi``, the clock) and
counters into ``OUT.npz``, for the test to compare with ``np.array_equal``.
"""

import json
import sys
import warnings
from pathlib import Path

import numpy as np

from ase_reversible.lammps import finalize_mpi, import_lammps
from ase_reversible.lammps.nose import ReversibleLammpsNose
from ase_reversible.lammps.nose import take_restart_state

import lammps_systems
from lammps_systems import fcc_box

lammps = import_lammps()

SYSTEMS = {
    # 256 atoms of a Lennard-Jones liquid in reduced units, heated from
    # T* = 1 towards the thermostat's 1.5.
    'lj': fcc_box('lj', 4, 1.0, 87287, mom=True),
    # A binary mixture: two masses, so two per-type sums.
    'lj-binary': fcc_box('lj-binary', 4, 1.5, 87287, mom=True),
    # 500 argon atoms (metal units) at 80 K, thermostat at 100 K.
    'argon': fcc_box('argon', 5, 80, 4928459, mom=True),
}

TIMESTEPS = {'lj': 2.0**-8, 'lj-binary': 2.0**-8, 'argon': 2.0**-9}
THERMOSTATS = {'lj': (1.5, 0.5), 'lj-binary': (1.5, 0.5),
               'argon': (100.0, 0.5)}


def start(system, restart=None):
    return lammps_systems.start(lammps, SYSTEMS[system], TIMESTEPS[system],
                                restart)


def lammps_rank(lmp):
    return lmp.extract_setting('world_rank')


def equilibrate(lmp, temperature, tdamp, steps, keep=False):
    lmp.command(f'fix warm all nvt temp {temperature} {temperature} {tdamp}')
    lmp.command(f'run {steps}')
    if not keep:
        lmp.command('unfix warm')


def state(rev):
    ids, x, v = rev.gather()
    s, pi, clock = rev.s, rev.pi, rev.clock
    q = rev.velocity_quantum
    virtual = np.rint(v * (s / q)) * q
    return {'ids': ids, 'x': x, 'v': v, 'vv': virtual,
            'shown': virtual / s, 'thermostat': np.array([s, pi, clock])}


def main(job, out, **options):
    system = options.pop('system', 'lj')
    steps = int(options.pop('steps', 200))
    files = Path(options.pop('files', '.'))
    every = int(options.pop('every', 10))
    warm = int(options.pop('warm', 2000))
    early_init = int(options.pop('early_init', 0))
    temperature, tdamp = THERMOSTATS[system]
    settings = {key: (value if key == 'path' else float(value))
                for key, value in options.items()}
    settings.setdefault('temperature', temperature)
    settings.setdefault('tdamp', tdamp)
    dt = TIMESTEPS[system]
    refused = None
    lmp = start(system, restart=files / 'half.restart'
                if job == 'restart-read' else None)
    if job == 'refused':
        # Each refused before anything is defined: the next one starts
        # from the same LAMMPS.
        refused = []
        for bad in (dict(path='python'), dict(temperature=-1.0),
                    dict(tdamp=float('nan'))):
            try:
                ReversibleLammpsNose(lmp, **{**settings, **bad})
            except ValueError as error:
                refused.append(str(error))
        # Atoms moving as a whole: warned about, not refused.
        lmp.command('velocity all set 0.5 0.0 0.0 sum yes')
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter('always')
            ReversibleLammpsNose(lmp, **settings).run(0)
        moving = [str(w.message) for w in caught
                  if 'move as a whole' in str(w.message)]
        if lammps_rank(lmp) == 0:
            np.savez(out, counters=json.dumps({'refused': refused,
                                               'moving': moving}))
        lmp.close()
        return
    if job == 'restart-read' and early_init:
        # The thermostat's state taken right after read_restart, then a
        # command that initialises LAMMPS (which drops a restart file's
        # fix state unless the fix is defined) before the integrator.
        counters_taken = take_restart_state(lmp)
        lmp.command('run 0')
    if job == 'sample':
        # Near equilibrium first (LAMMPS's own thermostat), so that the
        # exact run does not begin with the thermostat's large swing from
        # a lattice.
        equilibrate(lmp, temperature, tdamp, warm)
    if job == 'blowup':
        # From step 21 on, a force beyond any grid: the step's kick is
        # refused after its drift, which fix_modify undo takes back.
        lmp.command(f'variable fx equal (time>{20.5 * dt!r})*1e300')
        lmp.command('fix push all addforce v_fx 0.0 0.0')
    rev = ReversibleLammpsNose(lmp, **settings)
    rev.run(0)
    states = {('half' if job == 'restart-read' else 'start'): state(rev)}
    counters = {}

    if job == 'reversal':
        rev.mark_anchor()
        rev.run(steps)
        states['out'] = state(rev)
        lmp.command(f'timestep {-dt!r}')
        rev.run(steps)
        states['back'] = state(rev)
        off, largest = rev.compare_with_anchor()
        counters['anchor'] = [off, largest, rev.thermostat_at_anchor]
    elif job == 'restart-write':
        rev.run(steps)
        lmp.command(f'write_restart {files / "half.restart"}')
        states['half'] = state(rev)
        rev.run(steps)
        states['end'] = state(rev)
    elif job == 'restart-read':
        counters['restored'] = rev.restored
        if early_init:
            counters['taken'] = counters_taken
        rev.run(steps)
        states['end'] = state(rev)
        lmp.command(f'timestep {-dt!r}')
        rev.run(2 * steps)
        states['start'] = state(rev)
    elif job in ('unstable', 'blowup'):
        # 'unstable': a thermostat far too stiff for the time step, s
        # swings to zero (any error is reported to the test); 'blowup':
        # only a FloatingPointError may stop the run.
        expected = Exception if job == 'unstable' else FloatingPointError
        step = rev.step
        try:
            rev.run(steps)
        except expected as error:  # noqa: BLE001 - reported to the test
            refused = f'{type(error).__name__}: {error}'
        counters['stopped_at'] = rev.step - step
        states['stopped'] = state(rev)
        lmp.command(f'timestep {-dt!r}')
        rev.run(rev.step - step)
        states['back'] = state(rev)
    elif job == 'sample':
        # The reversible thermostat and LAMMPS's fix nvt from the same
        # equilibrated state: the kinetic temperature every `every` steps.
        kinetic = {'exact': [], 'fix nvt': []}
        for _ in range(steps // every):
            rev.run(every)
            kinetic['exact'].append(rev.kinetic_temperature())
        reference = start(system)
        equilibrate(reference, temperature, tdamp, warm, keep=True)
        for _ in range(steps // every):
            reference.command(f'run {every} pre no post no')
            kinetic['fix nvt'].append(reference.get_thermo('temp'))
        counters['kinetic'] = kinetic
        counters['dof'] = rev.degrees_of_freedom
        reference.close()
    else:
        raise SystemExit(f'unknown job {job}')
    counters.update({'clean_recomputations': rev.clean_recomputations,
                     'velocity_quantum': rev.velocity_quantum,
                     'quanta': rev.quanta, 'ranks': rev.world.size})
    if refused is not None:
        counters['refused'] = refused
    if rev.rank == 0:
        arrays = {f'{name}_{part}': value for name, saved in states.items()
                  for part, value in saved.items()}
        np.savez(out, counters=json.dumps(counters), **arrays)
    lmp.close()


if __name__ == '__main__':
    main(sys.argv[1], sys.argv[2],
         **dict(arg.split('=', 1) for arg in sys.argv[3:]))
    finalize_mpi()
