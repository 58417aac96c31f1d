"""One LAMMPS job of tests/test_lammps.py, on every rank of ``mpiexec``.

``python lammps_worker.py JOB OUT.npz [key=value ...]``: builds a system,
runs the job with :class:`ReversibleLammps` and has rank 0 save the
gathered states (ids, unwrapped positions, velocities) and counters into
``OUT.npz``, for the test to compare with ``np.array_equal``.
"""

import json
import sys
from pathlib import Path

import numpy as np

from ase_reversible.lammps import ReversibleLammps, import_lammps

lammps = import_lammps()

DT = 0.001953125  # 2^-9 ps

SYSTEMS = {
    # 864 atoms of argon at 240 K: atoms cross the periodic faces and the
    # boundary between two ranks within a few hundred steps.
    'argon': """units metal
boundary p p p
lattice fcc 5.26
region box block 0 6 0 6 0 6
create_box 1 box
create_atoms 1 box
mass 1 39.948
pair_style lj/cut 8.5
pair_coeff 1 1 0.0104 3.40
velocity all create 240 4928459 loop geom""",
    # 500 atoms of copper at 1200 K under EAM (a many-body potential).
    'copper': """units metal
boundary p p p
lattice fcc 3.615
region box block 0 5 0 5 0 5
create_box 1 box
create_atoms 1 box
mass 1 63.546
pair_style eam
pair_coeff * * {potential}
velocity all create 1200 87287 loop geom""",
    # 177 argon atoms of a ball in a shrink-wrapped box, at 60 K.
    'cluster': """units metal
boundary s s s
lattice fcc 5.26
region box block -6 6 -6 6 -6 6
create_box 1 box
region ball sphere 0 0 0 2.2
create_atoms 1 region ball
mass 1 39.948
pair_style lj/cut 8.5
pair_coeff 1 1 0.0104 3.40
velocity all create 60 4928459 loop geom""",
    # A binary Lennard-Jones mixture in reduced units, two masses.
    'lj-binary': """units lj
boundary p p p
lattice fcc 0.8442
region box block 0 5 0 5 0 5
create_box 2 box
create_atoms 1 box
set type 1 type/fraction 2 0.2 12393
mass 1 1.0
mass 2 2.0
pair_style lj/cut 2.5
pair_coeff 1 1 1.0 1.0
pair_coeff 2 2 1.0 0.9
pair_coeff 1 2 1.2 0.95
velocity all create 1.5 87287 loop geom""",
}

TIMESTEPS = {'argon': DT, 'copper': DT, 'cluster': DT, 'lj-binary': 2.0**-8}


def start(system, restart=None, data=None):
    lmp = lammps.lammps(cmdargs=['-log', 'none', '-screen', 'none'])
    if restart or data:
        lines = SYSTEMS[system].splitlines()
        lmp.command('units lj' if system == 'lj-binary' else 'units metal')
        if data:  # a data file's Pair Coeffs need the style first
            lmp.command(next(line for line in lines
                             if line.startswith('pair_style')))
        lmp.command(f'read_restart {restart}' if restart
                    else f'read_data {data}')
        for line in lines:
            if line.split()[0] in ('mass', 'pair_style', 'pair_coeff'):
                lmp.command(line.format(potential=potential()))
    else:
        for line in SYSTEMS[system].splitlines():
            lmp.command(line.format(potential=potential()))
    lmp.command(f'timestep {TIMESTEPS[system]!r}')
    return lmp


def potential():
    return (Path(lammps.__file__).parent / 'share' / 'lammps' / 'potentials'
            / 'Cu_u3.eam')


def main(job, out, **options):
    system = options.pop('system', 'argon')
    steps = int(options.pop('steps', 300))
    files = Path(options.pop('files', '.'))
    settings = {key: float(value) for key, value in options.items()}
    refused = None
    if job in ('restart-read', 'data-read'):
        kind = job.split('-')[0]
        lmp = start(system, **{kind: files / f'half.{kind}'})
    else:
        lmp = start(system)
    if job == 'frozen':
        # A force fix defined before the exact runs: it acts first.
        lmp.command('group frozen id 1:50')
        lmp.command('velocity frozen set 0.0 0.0 0.0')
        lmp.command('fix freeze frozen setforce 0.0 0.0 0.0')
    rev = ReversibleLammps(lmp, **settings)
    rev.run(0)
    first = 'half' if job.endswith('-read') else 'start'
    states = {first: rev.gather()}

    def back(steps):
        lmp.command(f'timestep {-TIMESTEPS[system]!r}')
        rev.run(steps)

    ended_recomputed = []
    if job in ('reversal', 'frozen'):
        rev.run(steps)
        ended_recomputed.append(rev.last_recomputed_step == rev.step)
        states['out'] = rev.gather()
        back(steps)
        ended_recomputed.append(rev.last_recomputed_step == rev.step)
        states['back'] = rev.gather()
    elif job == 'restart-write':
        # Out and on in one process, writing a restart and a data file
        # half-way: the reference a restart must continue bit for bit.
        rev.run(steps)
        lmp.command(f'write_restart {files / "half.restart"}')
        lmp.command(f'write_data {files / "half.data"}')
        states['half'] = rev.gather()
        rev.run(steps)
        states['end'] = rev.gather()
    elif job.endswith('-read'):
        rev.run(steps)
        states['end'] = rev.gather()
        back(2 * steps)
        states['start'] = rev.gather()
    elif job == 'refused-timestep':
        rev.run(steps)
        lmp.command('timestep 0.0025')
        try:
            rev.run(10)
        except ValueError as error:
            refused = str(error)
        back(steps)
        states['back'] = rev.gather()
    elif job == 'overlap':
        # An atom dropped 0.05 Å from another: forces beyond any grid.
        rev.run(steps)
        lmp.command('create_atoms 1 single 0.05 0.0 0.0 units box')
        lmp.command('velocity all create 240 4928459 loop geom')
        rev.run(0)
        states = {'before': rev.gather()}
        step = rev.step
        try:
            rev.run(10)
        except FloatingPointError as error:
            refused = f'{error} (step {step} -> {rev.step})'
        states['after'] = rev.gather()
    else:
        raise SystemExit(f'unknown job {job}')
    counters = {'clean_recomputations': rev.clean_recomputations,
                'sort_retries': rev.sort_retries,
                'max_observed_noise': rev.max_observed_noise,
                'velocity_quantum': rev.velocity_quantum,
                'ranks': rev.world.size,
                'ended_recomputed': ended_recomputed}
    if refused is not None:
        counters['refused'] = refused
    if rev.rank == 0:
        arrays = {f'{name}_{part}': value for name, state in states.items()
                  for part, value in zip(('ids', 'x', 'v'), state)}
        np.savez(out, counters=json.dumps(counters), **arrays)
    lmp.close()


if __name__ == '__main__':
    main(sys.argv[1], sys.argv[2],
         **dict(arg.split('=', 1) for arg in sys.argv[3:]))
