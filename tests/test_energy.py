"""Energy behaviour next to VelocityVerlet at the same time step.

Fixed point changes each step by at most half a quantum per coordinate,
far below the integrator's own error, so the total energy should fluctuate
as VelocityVerlet's does and show no drift -- also in the guarded mode,
whose momentum quantum is coarser.  Over 20,000 steps of a cluster the mean
energy of the last fifth differs from the first fifth's by one to three
standard deviations for VelocityVerlet too, with a sign that varies from
seed to seed, so both criteria are taken over three seeds.
"""

import numpy as np
import pytest
from ase.md.verlet import VelocityVerlet

from ase_reversible import ReversibleVerlet

from conftest import CALCULATORS, DT, argon_cluster, copper_bulk
from tiers import SLOW

# Statistics over 20,000 steps and three seeds: the long tier only.
pytestmark = SLOW

SEEDS = (0, 1, 2)
CASES = {
    'Ar55 solid asap-lj': (lambda s: argon_cluster(3, 30, s), 'asap-lj',
                           20000),
    'Ar55 liquid asap-lj': (lambda s: argon_cluster(3, 60, s), 'asap-lj',
                            20000),
    'Cu108 asap-emt': (lambda s: copper_bulk((3, 3, 3), 600, s), 'asap-emt',
                       2000),
}


def total_energy_series(dyn, steps):
    energies = []
    dyn.attach(lambda: energies.append(dyn.atoms.get_total_energy()))
    dyn.run(steps)
    return np.array(energies)


def drift(energies):
    """Mean energy over the last fifth minus that over the first fifth."""
    k = len(energies) // 5
    return energies[-k:].mean() - energies[:k].mean()


def run(build, calc, steps, seed, make_dyn):
    atoms = build(seed)
    atoms.calc = CALCULATORS[calc]()
    return total_energy_series(make_dyn(atoms), steps)


@pytest.mark.parametrize('scheme', ['velocity', 'position'])
@pytest.mark.parametrize('case', list(CASES))
def test_energy_behaves_like_velocity_verlet(case, scheme):
    build, calc, steps = CASES[case]
    rev = [run(build, calc, steps, s,
               lambda a: ReversibleVerlet(a, DT, scheme=scheme))
           for s in SEEDS]
    vv = [run(build, calc, steps, s, lambda a: VelocityVerlet(a, DT))
          for s in SEEDS]

    # Fluctuations of the same size.  Position Verlet has its own error
    # constant, hence a wider band.
    ratio = np.median([r.std() / v.std() for r, v in zip(rev, vv)])
    assert (0.7 < ratio < 1.4) if scheme == 'velocity' else (0.4 < ratio < 2.5)
    # No systematic drift: signed drifts average out, and their size is
    # VelocityVerlet's.
    d_rev = np.array([drift(r) for r in rev])
    d_vv = np.array([drift(v) for v in vv])
    assert np.mean(np.abs(d_rev)) < 2.5 * np.mean(np.abs(d_vv))
    assert abs(np.mean(d_rev)) < 2 * np.mean([r.std() for r in rev])
