"""One case of benchmarks/lammps_cost.py (or of its study lammps_scale), on
every rank of ``mpiexec``.

``mpiexec -n R python lammps_worker.py CASE_JSON LOG_DIR``: one LAMMPS
instance per integrator named in the case, rotating blocks of the same
steps, single-step blocks, timed ``run 0`` setups and the MPI maximum from
Python; rank 0 prints one JSON line.  Each block's LAMMPS log (in LOG_DIR)
is read back for the loop time and the timer breakdown.
"""

from __future__ import annotations

import common  # noqa: F401  (first: pins BLAS threads before numpy)

import json
import re
import statistics
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Optional

from ase_reversible.lammps import (ReversibleLammps, ReversibleLammpsNose,
                                   finalize_mpi, import_lammps)

lammps = import_lammps()

#: 2^-9 ps: a power of two, as the exact integrator needs; every instance.
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


@dataclass(frozen=True)
class Integrator:
    """``attach(lmp, case) -> (run, rev)`` defines the integrator on a fresh
    instance: ``run(n)`` runs n steps, ``rev`` is its ReversibleLammps
    (None for LAMMPS's own fixes); ``reference`` names the entry of
    ``INTEGRATORS`` it is measured against (None for a reference)."""
    attach: Callable
    reference: Optional[str]
    label: str


def _lammps_fix(command):
    """LAMMPS's own fix; ``command`` may name ``{T}`` and ``{tdamp}``
    (the case's thermostat)."""
    def attach(lmp, case):
        lmp.command(command.format(T=THERMOSTAT_K[case['system']],
                                   tdamp=TDAMP_PS))
        return (lambda n: lmp.command(f'run {n}')), None
    return attach


def _reversible(path):
    def attach(lmp, case):
        rev = ReversibleLammps(lmp, path=path)
        return rev.run, rev
    return attach


def _reversible_nvt(lmp, case):
    rev = ReversibleLammpsNose(lmp, temperature=THERMOSTAT_K[case['system']],
                               tdamp=TDAMP_PS, path='compiled')
    return rev.run, rev


#: Thermostat targets, K: half the temperature the velocities are drawn
#: at, which a lattice start shares out into the potential energy.
THERMOSTAT_K = {'argon': 50.0, 'copper': 300.0}
#: Thermostat damping time, ps (128 steps), for fix nvt and reversible nvt.
TDAMP_PS = 0.25


#: Every integrator a case may name.  A thermostat is one entry for
#: LAMMPS's fix and one for the exact one, whose ``reference`` names it.
INTEGRATORS = {
    'nve': Integrator(_lammps_fix('fix nve all nve'), None, 'fix nve'),
    'compiled': Integrator(_reversible('compiled'), 'nve',
                           'exact, compiled'),
    'python': Integrator(_reversible('python'), 'nve', 'exact, Python'),
    'nvt': Integrator(_lammps_fix('fix nvt all nvt temp {T} {T} {tdamp}'),
                      None, 'fix nvt'),
    'exact_nvt': Integrator(_reversible_nvt, 'nvt', 'reversible nvt'),
}


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
    # LAMMPS's default, and what ReversibleLammps sets: said for every one.
    lmp.command('neigh_modify delay 0 every 1 check yes')
    return lmp


def read_log(path: Path) -> dict:
    """Loop time and timer breakdown (average over ranks) of a LAMMPS log,
    summed over its runs."""
    text = path.read_text()
    loops = re.findall(r'^Loop time of (\S+) on \d+ procs', text, re.M)
    breakdown = {}
    for name in TIMER_SECTIONS:
        for row in re.findall(rf'^{name}\s*\|([^\n]*)', text, re.M):
            cells = [c.strip() for c in row.split('|')]
            # min | avg | max | %varavg | %total; Other has only avg.
            avg = float(cells[1]) if cells[1] else float(cells[0] or 0)
            breakdown[name] = breakdown.get(name, 0.0) + avg
    return {'loop_seconds': sum(float(t) for t in loops),
            'breakdown_seconds': breakdown}


class Instance:
    """One LAMMPS instance of the case and its integrator."""

    def __init__(self, name, case):
        self.name = name
        self.lmp = start(case)
        self.run, self.rev = INTEGRATORS[name].attach(self.lmp, case)

    def clean(self):
        return 0 if self.rev is None else self.rev.clean_recomputations


def reversal(case):
    """``case['steps']`` steps out and back on the compiled path from the
    default grid: the grid, the steps whose flagged kicks were recomputed
    (and where), their wall time against the run's, and the landing."""
    lmp = start(case)
    rev = ReversibleLammps(lmp, path='compiled')
    rev.mark_anchor()
    rev.run(0)
    times = {}
    for leg, dt in (('out', TIMESTEP), ('back', -TIMESTEP)):
        lmp.command(f'timestep {dt!r}')
        before = (rev.clean_recomputations, rev.recomputed_atoms,
                  rev.recompute_seconds)
        rev.world.max(0.0)
        started = time.perf_counter()
        rev.run(case['steps'])
        rev.world.max(0.0)
        times[leg] = {
            'wall_seconds': time.perf_counter() - started,
            'recomputed_steps': rev.clean_recomputations - before[0],
            'recomputed_atoms': rev.recomputed_atoms - before[1],
            'recompute_seconds': rev.recompute_seconds - before[2]}
    off, largest = rev.compare_with_anchor()
    result = {'natoms': int(lmp.get_natoms()), 'ranks': rev.world.size,
              'steps': case['steps'], 'legs': times,
              'velocity_quantum': rev.velocity_quantum,
              'velocity_bits': rev.velocity_bits,
              'global_reason': rev.global_reason,
              'sort_retries': rev.sort_retries,
              'atoms_off_anchor': off, 'largest_difference': largest,
              'max_observed_noise': rev.max_observed_noise,
              'noise_bound_at_max': rev.noise_bound_at_max}
    rank = rev.rank
    lmp.close()
    if rank == 0:
        print(json.dumps(result), flush=True)


def main(case, log_dir):
    if case.get('job') == 'reversal':
        return reversal(case)
    log_dir = Path(log_dir)
    names = list(case['integrators'])
    instances = {name: Instance(name, case) for name in names}
    exact = [i for i in instances.values() if i.rev is not None]
    world = exact[0].rev.world
    rank = exact[0].rev.rank
    paths = {i.name: i.rev.path for i in exact}
    for name, path in paths.items():
        # 'auto' must not stand in for what was asked: a fallback would
        # measure the Python path twice.
        if name in ('compiled', 'python') and path != name:
            raise RuntimeError(f'{name} instance runs the {path} path')

    def sync():
        world.max(0.0)

    def timed(instance, steps):
        """One block: wall seconds between barriers (the slowest rank's),
        CPU seconds of this process during the run (the largest over the
        ranks), and on rank 0 its LAMMPS log read back."""
        path = log_dir / f'{instance.name}.log'
        instance.lmp.command(f'log {path}')
        clean = instance.clean()
        sync()
        started, cpu_started = time.perf_counter(), time.process_time()
        instance.run(steps)
        cpu = time.process_time() - cpu_started
        sync()
        wall = time.perf_counter() - started
        instance.lmp.command('log none')
        block = {'wall_seconds': wall,
                 'cpu_seconds': float(world.max(cpu)[0]), 'steps': steps,
                 'clean_recomputations': instance.clean() - clean}
        if rank == 0:
            block.update(read_log(path))
        return block

    for name in names:
        timed(instances[name], case['warmup_steps'])
    blocks = {name: [] for name in names}
    for r in range(case['rounds']):
        # The order rotates: each instance leads in rounds/len(names).
        shift = r % len(names)
        for name in names[shift:] + names[:shift]:
            blocks[name].append(timed(instances[name], case['steps']))

    # Blocks of one step: what a run costs besides its steps (the setup
    # and, on the exact side, the checks and fixes of rev.run), so that
    # (block of M - block of 1) / (M - 1) is a step of a long run.
    single = {name: [] for name in names}
    for _ in range(case['setups']):
        for name in names:
            single[name].append(timed(instances[name], 1))

    # A LAMMPS setup, as a clean recomputation does it (sort, lists,
    # forces); on an exact instance outside rev.run(), so its fine sort
    # bins are in force and no integrator fix is defined.
    setup = {name: [] for name in names}
    for _ in range(case['setups']):
        for name in names:
            sync()
            started = time.perf_counter()
            instances[name].lmp.command('run 0')
            sync()
            setup[name].append(time.perf_counter() - started)

    # The Python path's per-step collective, one MPI maximum through
    # ctypes; the compiled fix makes the same MPI_Allreduce from C++,
    # without the call's Python overhead.
    reduce_per_call = []
    for _ in range(case['reduce_blocks']):
        sync()
        started = time.perf_counter()
        for _ in range(case['reduce_calls']):
            world.max(0.0)
        reduce_per_call.append((time.perf_counter() - started)
                               / case['reduce_calls'])

    some = exact[0]
    result = {
        'natoms': int(some.lmp.get_natoms()),
        'ranks': world.size,
        'lammps_version': int(some.lmp.version()),
        'integrators': {name: {'label': INTEGRATORS[name].label,
                               'reference': INTEGRATORS[name].reference,
                               'path': paths.get(name)}
                        for name in names},
        'blocks': blocks,
        'single_step_blocks': single,
        'setup_median_seconds': {n: statistics.median(v)
                                 for n, v in setup.items()},
        'reduce_median_seconds_per_call': statistics.median(reduce_per_call),
    }
    for instance in instances.values():
        instance.lmp.close()
    if rank == 0:
        print(json.dumps(result), flush=True)


if __name__ == '__main__':
    main(json.loads(sys.argv[1]), sys.argv[2])
    finalize_mpi()
