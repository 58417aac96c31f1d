"""Other people's calculators through the shared checks.

ASE's LennardJones and EMT, and asap3's EMT where asap3 is installed: the
checks that apply to a calculator that declares no purity and has no
Hessian-vector product (the rest skip with the reason).  The package's own
calculators run them in their own test modules.
"""

from ase.calculators.emt import EMT

from calculator_conformance import CalculatorConformance
from conftest import (DT, argon_bulk, argon_cluster, ase_lj, copper_bulk,
                      copper_cluster, needs_asap3)


def _rattled(atoms):
    # A perfect crystal feels no forces: nothing to check them by.
    atoms.rattle(0.1, seed=4)
    return atoms


class TestAseLennardJones(CalculatorConformance):
    systems = {'cluster': lambda: argon_cluster(3, 80),
               'crystal': lambda: _rattled(argon_bulk((2, 2, 2), 80))}
    timestep = DT
    reversal_steps = 300
    # Its check_state has ASE's 1e-15 Å tolerance.
    exact_check_state = False
    # Measured 0.3-3.6e-9 of max|F|: its forces jump at rc (smooth=False).
    gradient_tolerance = 1e-7

    def make_calc(self, **parameters):
        calc = ase_lj()
        calc.set(**parameters)
        return calc


class TestAseEMT(CalculatorConformance):
    systems = {'cluster': lambda: copper_cluster(2, 600),
               'crystal': lambda: copper_bulk((2, 2, 2), 600)}
    timestep = DT
    reversal_steps = 300
    exact_check_state = False
    gradient_tolerance = 1e-7  # measured 0.7-1.6e-9 of max|F|

    def make_calc(self, **parameters):
        return EMT(**parameters)


class TestAsapEMT(TestAseEMT):
    def make_calc(self, **parameters):
        return needs_asap3().EMT(**parameters)
