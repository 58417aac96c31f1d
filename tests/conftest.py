"""Systems and calculators shared by the tests.

Every calculator here is a real one (ASE's or asap3's); builders return
fresh Atoms with thermal momenta drawn from a fixed seed.
"""

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
