"""One case of benchmarks/lammps_cost.py, on every rank of ``mpiexec``.

``mpiexec -n R python lammps_worker.py CASE_JSON LOG_DIR``: builds the same
system in two LAMMPS instances of this process, one integrated by
``fix nve`` and one by :class:`ReversibleLammps`, runs them in alternating
blocks of the same number of steps, then times a ``run 0`` setup on each
and the exact integrator's MPI maximum.  Rank 0 prints one JSON line.

CASE_JSON holds ``system`` ('argon' or 'copper'), ``cells`` (fcc unit
cells along x, y, z), ``steps`` (per block), ``warmup_steps``, ``rounds``,
``setups`` and ``reduce_blocks``/``reduce_calls``.  LOG_DIR receives a
LAMMPS log per block (``log FILE`` around each run), read back for LAMMPS's
loop time, its timer breakdown and the neighbour-list builds; the
instances are started with ``-screen none -log none``.
"""

from __future__ import annotations

import common  # noqa: F401  (first: pins BLAS threads before numpy)

import json
import re
import statistics
import sys
import time
from pathlib import Path

from ase_reversible.lammps import ReversibleLammps, import_lammps

lammps = import_lammps()

#: 2^-9 ps: a power of two, as the exact integrator needs; both instances.
TIMESTEP = 0.001953125

SYSTEMS = {
    # Argon, metal units, Lennard-Jones cut at 8.5 Å, 100 K.
    'argon': """units metal
boundary p p p
lattice fcc 5.26
region box block 0 {nx} 0 {ny} 0 {nz}
create_box 1 box
create_atoms 1 box
mass 1 39.948
pair_style lj/cut 8.5
pair_coeff 1 1 0.0104 3.40
velocity all create 100 4928459 loop geom""",
    # Copper under EAM (Cu_u3.eam of the wheel), 600 K.
    'copper': """units metal
boundary p p p
lattice fcc 3.615
region box block 0 {nx} 0 {ny} 0 {nz}
create_box 1 box
create_atoms 1 box
mass 1 63.546
pair_style eam
pair_coeff * * {potential}
velocity all create 600 87287 loop geom""",
}

#: Sections of LAMMPS's "MPI task timing breakdown".
TIMER_SECTIONS = ('Pair', 'Bond', 'Kspace', 'Neigh', 'Comm', 'Output',
                  'Modify', 'Other')


def potential():
    return (Path(lammps.__file__).parent / 'share' / 'lammps' / 'potentials'
            / 'Cu_u3.eam')


def start(case):
    lmp = lammps.lammps(cmdargs=['-screen', 'none', '-log', 'none'])
    nx, ny, nz = case['cells']
    for line in SYSTEMS[case['system']].format(
            nx=nx, ny=ny, nz=nz, potential=potential()).splitlines():
        lmp.command(line)
    lmp.command(f'timestep {TIMESTEP!r}')
    # LAMMPS's default, and what ReversibleLammps sets: said for both.
    lmp.command('neigh_modify delay 0 every 1 check yes')
    return lmp


def read_log(path: Path) -> dict:
    """Loop time, steps, timer breakdown (average over ranks) and neighbour
    builds of every run in a LAMMPS log, summed over its runs."""
    text = path.read_text()
    loops = re.findall(r'^Loop time of (\S+) on \d+ procs for (\d+) steps',
                       text, re.M)
    breakdown = {}
    for name in TIMER_SECTIONS:
        for row in re.findall(rf'^{name}\s*\|([^\n]*)', text, re.M):
            cells = [c.strip() for c in row.split('|')]
            # min | avg | max | %varavg | %total; Other has only avg.
            avg = float(cells[1]) if cells[1] else float(cells[0] or 0)
            breakdown[name] = breakdown.get(name, 0.0) + avg
    return {
        'runs': len(loops),
        'loop_seconds': sum(float(t) for t, _ in loops),
        'loop_steps': sum(int(n) for _, n in loops),
        'breakdown_seconds': breakdown,
        'neighbor_builds': sum(int(n) for n in re.findall(
            r'^Neighbor list builds = (\d+)', text, re.M)),
        'dangerous_builds': sum(int(n) for n in re.findall(
            r'^Dangerous builds = (\d+)', text, re.M)),
    }


def main(case, log_dir):
    log_dir = Path(log_dir)
    nve = start(case)
    nve.command('fix nve all nve')
    exact_lmp = start(case)
    rev = ReversibleLammps(exact_lmp)
    world, rank = rev.world, rev.rank

    def sync():
        world.max(0.0)

    def timed(name, lmp, run, steps):
        """Wall seconds of one block, slowest rank's, with its log read."""
        path = log_dir / f'{name}.log'
        lmp.command(f'log {path}')
        clean, retries = rev.clean_recomputations, rev.sort_retries
        sync()
        started = time.perf_counter()
        run(steps)
        sync()
        wall = time.perf_counter() - started
        lmp.command('log none')
        block = {'wall_seconds': wall, 'steps': steps,
                 'clean_recomputations': rev.clean_recomputations - clean,
                 'sort_retries': rev.sort_retries - retries}
        if rank == 0:
            block.update(read_log(path))
        return block

    runners = {'nve': (nve, lambda n: nve.command(f'run {n}')),
               'exact': (exact_lmp, rev.run)}
    names = list(runners)
    warmup = {name: timed(name, *runners[name], case['warmup_steps'])
              for name in names}
    blocks = {name: [] for name in names}
    for r in range(case['rounds']):
        # The order alternates: each instance runs first in half the rounds.
        for name in names[r % 2:] + names[:r % 2]:
            blocks[name].append(timed(name, *runners[name], case['steps']))

    # A LAMMPS setup, as a clean recomputation does it (sort, lists,
    # forces); on the exact instance outside rev.run(), so its fine sort
    # bins are in force and no integrator fix is defined.
    setup = {name: [] for name in names}
    for _ in range(case['setups']):
        for name in names:
            lmp = runners[name][0]
            sync()
            started = time.perf_counter()
            lmp.command('run 0')
            sync()
            setup[name].append(time.perf_counter() - started)

    # The per-step collective of the exact path: one MPI maximum.
    reduce_per_call = []
    for _ in range(case['reduce_blocks']):
        sync()
        started = time.perf_counter()
        for _ in range(case['reduce_calls']):
            world.max(0.0)
        reduce_per_call.append((time.perf_counter() - started)
                               / case['reduce_calls'])

    natoms = int(exact_lmp.get_natoms())
    result = {
        'natoms': natoms,
        'ranks': world.size,
        'lammps_version': int(exact_lmp.version()),
        'nlocal_rank0': int(exact_lmp.extract_setting('nlocal')),
        'velocity_quantum': rev.velocity_quantum,
        'position_quantum': rev.position_quantum,
        'sort_bin': rev.sort_bin,
        'force_noise': rev.force_noise,
        'max_observed_noise': rev.max_observed_noise,
        'noise_bound_at_max': rev.noise_bound_at_max,
        'warmup': warmup,
        'blocks': blocks,
        'setup_seconds': setup,
        'setup_median_seconds': {n: statistics.median(v)
                                 for n, v in setup.items()},
        'reduce_seconds_per_call': reduce_per_call,
        'reduce_median_seconds_per_call': statistics.median(reduce_per_call),
    }
    nve.close()
    exact_lmp.close()
    if rank == 0:
        print(json.dumps(result), flush=True)


if __name__ == '__main__':
    main(json.loads(sys.argv[1]), sys.argv[2])
