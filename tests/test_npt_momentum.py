"""The NPT integrators hold the total momentum of a start at rest at
exactly zero, as ASE's MTK classes keep it (their scalings and force sums
leave it at zero): FixCom's integer balance on every kick and O step.

ASE's own check is ``np.allclose(np.sum(atoms.get_momenta(), axis=0),
0.0)`` after 100 steps of a ``Stationary`` start; here the exact variable,
the sum of the counts of ``pi``, is compared with zero by
``np.array_equal``, and the run still goes back bit for bit."""

import numpy as np
import pytest
from ase import units
from ase.build import bulk
from ase.calculators.emt import EMT
from ase.io import Trajectory, read
from ase.md.velocitydistribution import Stationary

from ase_reversible import ReversibleIsotropicNPT, ReversibleNPT
from ase_reversible.core.codec import encode
from conftest import copper_bulk
from tiers import SLOW, tiered

DT = 2 * units.fs
CLASSES = {'isotropic': (ReversibleIsotropicNPT, (2, 2, 2)),
           'full-cell': (ReversibleNPT, (2, 2, 2))}


def start(shape, at_rest=True):
    atoms = copper_bulk(shape, 300)
    if at_rest:
        Stationary(atoms)
    atoms.calc = EMT()
    return atoms


def npt(cls, atoms, **kwargs):
    return cls(atoms, DT, temperature_K=300, pressure_au=1.0 * units.GPa,
               tdamp=50 * units.fs, pdamp=100 * units.fs, **kwargs)


def net_counts(dyn):
    return dyn.system.p.ints.sum(axis=0)


@pytest.mark.parametrize('kind', tiered(CLASSES, quick=['isotropic']))
def test_a_start_at_rest_keeps_a_total_momentum_of_exactly_zero(kind):
    cls, shape = CLASSES[kind]
    atoms = start(shape)
    dyn = npt(cls, atoms, seed=7)
    assert np.array_equal(net_counts(dyn), np.zeros(3, np.int64))
    state = dyn.engine.snapshot()
    seen = (atoms.positions.copy(), atoms.get_momenta(),
            atoms.cell.array.copy())
    dyn.run(50)
    assert np.array_equal(net_counts(dyn), np.zeros(3, np.int64))
    # ASE's assertion, as its MTK test makes it.
    assert np.allclose(np.sum(atoms.get_momenta(), axis=0), 0.0)
    dyn.reverse()
    dyn.run(50)
    now = dyn.engine.snapshot()
    for name, counts in state.items():
        assert np.array_equal(now[name], counts), name
    for a, b in zip((atoms.positions, atoms.get_momenta(), atoms.cell.array),
                    seen):
        assert np.array_equal(a, b)


def test_a_thermal_start_not_at_rest_is_left_as_it_was():
    # Its net momentum (about sqrt(N m kT)) is no rounding: the run keeps
    # the counts, and the bits, it had before the balance existed.
    atoms = start((2, 2, 2), at_rest=False)
    momenta = atoms.get_momenta()
    dyn = npt(ReversibleIsotropicNPT, atoms, seed=7)
    assert dyn.system.centre is None
    assert np.array_equal(dyn.system.p.ints,
                          encode(momenta, dyn.system.p.quantum, 'momentum'))


def test_a_frame_of_a_run_at_rest_resumes_holding_it(tmp_path):
    atoms = start((2, 2, 2))
    dyn = npt(ReversibleIsotropicNPT, atoms, seed=7)
    with Trajectory(tmp_path / 'run.traj', 'w', atoms) as traj:
        dyn.attach(traj.write, interval=10)
        dyn.run(10)
        dyn.write_buffer(tmp_path / 'buffer.npz')
    frame = read(tmp_path / 'run.traj', index=-1)
    frame.calc = EMT()
    again = npt(ReversibleIsotropicNPT, frame, buffer=tmp_path / 'buffer.npz')
    assert again.system.centre is not None
    dyn.observers.clear()
    dyn.run(20)
    again.run(20)
    for name, counts in dyn.engine.snapshot().items():
        assert np.array_equal(again.engine.snapshot()[name], counts), name
    assert np.array_equal(net_counts(again), np.zeros(3, np.int64))


def test_momenta_set_between_runs_keep_a_zero_total():
    atoms = start((2, 2, 2))
    dyn = npt(ReversibleIsotropicNPT, atoms, seed=7)
    dyn.run(5)
    atoms.set_momenta(atoms.get_momenta() + [0.1, 0.0, 0.0])
    with pytest.warns(Warning):
        dyn.run(5)
    assert np.array_equal(net_counts(dyn), np.zeros(3, np.int64))


@SLOW
@pytest.mark.parametrize('cls', (ReversibleIsotropicNPT, ReversibleNPT))
def test_ase_mtk_test_system_keeps_a_zero_total(cls):
    # ASE's MTK test system: hcp Cu, a cell with a tilt.
    atoms = bulk('Cu', 'hcp', a=2.53, c=4.11).repeat(2)
    rng = np.random.default_rng(0)
    kT = units.kB * 300
    atoms.set_momenta(rng.standard_normal((len(atoms), 3))
                      * np.sqrt(atoms.get_masses()[:, None] * kT))
    Stationary(atoms)
    atoms.calc = EMT()
    dyn = cls(atoms, 1 * units.fs, temperature_K=300,
              pressure_au=10.0 * units.GPa, tdamp=100 * units.fs,
              pdamp=1000 * units.fs, seed=3)
    dyn.run(100)
    assert np.allclose(np.sum(atoms.get_momenta(), axis=0), 0.0)
    assert np.array_equal(net_counts(dyn), np.zeros(3, np.int64))
