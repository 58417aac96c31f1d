"""One LAMMPS job of tests/test_lammps.py, on every rank of ``mpiexec``.

``python lammps_worker.py JOB OUT.npz [key=value ...]``: builds a system,
runs the job with :class:`ReversibleLammps` and has rank 0 save the
gathered states (ids, unwrapped positions, velocities) and counters into
``OUT.npz``, for the test to compare with ``np.array_equal``.

``path=compiled|python`` chooses who runs the step (compiled by default,
never ``auto``: a plugin that fails to build must fail the test, not fall
back); ``back_path=P`` switches to path P after the run out (jobs
``reversal`` and ``frozen``), so the run back is taken by the other path.
"""

import json
import sys
from pathlib import Path

import numpy as np

from ase_reversible.lammps import ReversibleLammps, finalize_mpi, import_lammps

import lammps_systems
from lammps_systems import fcc_box

lammps = import_lammps()

DT = 0.001953125  # 2^-9 ps

SYSTEMS = {
    # 864 atoms of argon at 240 K: atoms cross the periodic faces and the
    # boundary between two ranks within a few hundred steps.
    'argon': fcc_box('argon', 6, 240, 4928459),
    # 500 atoms of copper at 1200 K under EAM (a many-body potential).
    'copper': fcc_box('copper', 5, 1200, 87287),
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
    'lj-binary': fcc_box('lj-binary', 5, 1.5, 87287),
}

TIMESTEPS = {'argon': DT, 'copper': DT, 'cluster': DT, 'lj-binary': 2.0**-8}


def start(system, restart=None, data=None):
    return lammps_systems.start(
        lammps, SYSTEMS[system].format(potential=potential()),
        TIMESTEPS[system], restart, data)


def potential():
    return (Path(lammps.__file__).parent / 'share' / 'lammps' / 'potentials'
            / 'Cu_u3.eam')


#: Jobs that chain others in one process, each on a new LAMMPS instance:
#: one process start (about 1.5 s) instead of two or three.
#: ``paths``: ``reversal`` out on each path and back on the other, saved
#: as ``compiled.NAME`` and ``python.NAME``; ``restart-across``:
#: ``restart-write`` on ``path``, then ``restart-read`` and ``data-read``
#: on the other path (the files carry everything from one instance to the
#: next), saved as ``write.NAME``, ``restart.NAME`` and ``data.NAME``.
PATHS = ('compiled', 'python')


def main(job, out, **options):
    system = options.pop('system', 'argon')
    steps = int(options.pop('steps', 300))
    files = Path(options.pop('files', '.'))
    path = options.pop('path', 'compiled')
    back_path = options.pop('back_path', path)
    # A force fix that does nothing keeps the compiled fix's flagged kicks
    # on the global setup (it cannot replay a fix that changes forces).
    global_setup = bool(int(options.pop('global_setup', 0)))
    settings = {key: float(value) for key, value in options.items()}
    if job == 'paths':
        legs = [(first, 'reversal', first, PATHS[1 - PATHS.index(first)])
                for first in PATHS]
    elif job == 'restart-across':
        then = PATHS[1 - PATHS.index(path)]
        legs = [('write', 'restart-write', path, path),
                ('restart', 'restart-read', then, then),
                ('data', 'data-read', then, then)]
    else:
        legs = [(None, job, path, back_path)]
    states, counters = {}, {}
    for prefix, leg, first, second in legs:
        leg_states, leg_counters, rank = session(
            leg, system, steps, files, first, second, settings, global_setup)
        if prefix is None:
            states, counters = leg_states, leg_counters
        else:
            states.update((f'{prefix}.{name}', state)
                          for name, state in leg_states.items())
            counters[prefix] = leg_counters
            counters.setdefault('runs', leg_counters['runs'])
    if rank == 0:
        arrays = {f'{name}_{part}': value for name, state in states.items()
                  for part, value in zip(('ids', 'x', 'v'), state)}
        np.savez(out, counters=json.dumps(counters), **arrays)


def session(job, system, steps, files, path, back_path, settings,
            global_setup=False):
    """One job on a new LAMMPS instance: its states, counters and rank."""
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
    if global_setup:
        lmp.command('fix keep all setforce NULL NULL NULL')
    rev = ReversibleLammps(lmp, path=path, **settings)
    rev.run(0)
    first = 'half' if job.endswith('-read') else 'start'
    states = {first: rev.gather()}

    # Every run out or back is tallied (see runs below).
    def forward(steps):
        rev.run(steps)
        tally()

    def back(steps):
        lmp.command(f'timestep {-TIMESTEPS[system]!r}')
        rev.run(steps)
        tally()

    ended_recomputed = []
    # Per run: (path, clean recomputations, sort retries), so that a test
    # can see each path did the work it is meant to check.
    runs = []

    def tally():
        done = sum(run[1] for run in runs), sum(run[2] for run in runs)
        runs.append((rev.path, rev.clean_recomputations - done[0],
                     rev.sort_retries - done[1]))

    def refusal(steps, error_type, message):
        # What the test is told when error_type stops a run: message(error).
        try:
            rev.run(steps)
        except error_type as error:
            return message(error)
        return None

    if job in ('reversal', 'frozen'):
        forward(steps)
        ended_recomputed.append(rev.last_recomputed_step == rev.step)
        states['out'] = rev.gather()
        rev.path = back_path
        back(steps)
        ended_recomputed.append(rev.last_recomputed_step == rev.step)
        states['back'] = rev.gather()
    elif job == 'restart-write':
        # Out and on in one process, writing a restart and a data file
        # half-way: the reference a restart must continue bit for bit.
        forward(steps)
        lmp.command(f'write_restart {files / "half.restart"}')
        lmp.command(f'write_data {files / "half.data"}')
        states['half'] = rev.gather()
        forward(steps)
        states['end'] = rev.gather()
    elif job.endswith('-read'):
        forward(steps)
        states['end'] = rev.gather()
        back(2 * steps)
        states['start'] = rev.gather()
    elif job == 'refused-timestep':
        forward(steps)
        lmp.command('timestep 0.0025')
        refused = refusal(10, ValueError, str)
        back(steps)
        states['back'] = rev.gather()
    elif job == 'overlap':
        # An atom dropped 0.05 Å from another: forces beyond any grid.
        forward(steps)
        lmp.command('create_atoms 1 single 0.05 0.0 0.0 units box')
        lmp.command('velocity all create 240 4928459 loop geom')
        rev.run(0)
        states = {'before': rev.gather()}
        step = rev.step
        refused = refusal(10, FloatingPointError,
                          lambda error: f'{error} (step {step} -> {rev.step})')
        states['after'] = rev.gather()
    else:
        raise SystemExit(f'unknown job {job}')
    counters = {'clean_recomputations': rev.clean_recomputations,
                'sort_retries': rev.sort_retries,
                'recomputed_atoms': rev.recomputed_atoms,
                'global_reason': rev.global_reason,
                'max_observed_noise': rev.max_observed_noise,
                'velocity_quantum': rev.velocity_quantum,
                'ranks': rev.world.size,
                'ended_recomputed': ended_recomputed,
                'path': rev.path, 'runs': runs}
    if refused is not None:
        counters['refused'] = refused
    rank = rev.rank
    lmp.close()
    return states, counters, rank


if __name__ == '__main__':
    main(sys.argv[1], sys.argv[2],
         **dict(arg.split('=', 1) for arg in sys.argv[3:]))
    finalize_mpi()
