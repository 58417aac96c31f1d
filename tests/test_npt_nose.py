"""The barostat with Nosé's thermostat, ``ReversibleIsotropicNPT(...,
thermostat='nose')``: exactly reversible with no buffer, its extended
energy conserved, the total momentum of a start at rest held at zero
(ASE's MTK tests' assertions), restarts bit for bit, and what it refuses.
"""

import warnings

import numpy as np
import pytest
from ase import units
from ase.build import bulk
from ase.calculators.emt import EMT
from ase.io import read, write
from ase.md.velocitydistribution import Stationary, thermalize_momenta

from ase_reversible import ReversibleIsotropicNPT, ReversibleNPT
from ase_reversible.md.npt.cell_nose import ReversibleNoseNPT
from ase_reversible.md.npt.nose import ReversibleIsotropicNoseNPT
from ase_reversible.core.record import read_record
from ase_reversible.md.machine import compare
from conftest import asap3, needs_asap3
from tiers import SLOW, tiered

DT = 1 * units.fs
TDAMP, PDAMP = 100 * units.fs, 1000 * units.fs
PRESSURE = 10 * units.GPa


def calculator():
    """asap3's EMT where installed (as ASE's MTK tests use), else ASE's."""
    return EMT() if asap3 is None else asap3.EMT()


def hcp_copper(at_rest=True, calc=None):
    """ASE's MTK tests' system: hcp Cu, 16 atoms, thermal at 300 K."""
    atoms = bulk('Cu', crystalstructure='hcp', a=2.53, c=4.11).repeat(2)
    atoms.calc = calculator() if calc is None else calc
    thermalize_momenta(atoms, 300, exact_temperature=True,
                       rng=np.random.default_rng(0))
    if at_rest:
        Stationary(atoms)
    return atoms


def nose_npt(atoms, tchain=1, **kwargs):
    return ReversibleIsotropicNPT(atoms, DT, 300, PRESSURE, TDAMP, PDAMP,
                                  tchain=tchain, thermostat='nose', **kwargs)


def counts(dyn):
    return {name: value.copy() for name, value in dyn.counts.items()}


def assert_counts_equal(dyn, reference):
    now = dyn.counts
    for name, value in reference.items():
        assert np.array_equal(now[name], value), name


def shown(atoms):
    return (atoms.positions.copy(), atoms.get_momenta(),
            atoms.cell.array.copy())


def assert_shown_equal(atoms, reference):
    for now, then in zip(shown(atoms), reference):
        assert np.array_equal(now, then)


def test_thermostat_nose_constructs_the_nose_class():
    dyn = nose_npt(hcp_copper())
    assert type(dyn) is ReversibleIsotropicNoseNPT
    assert isinstance(dyn, ReversibleIsotropicNPT)
    assert dyn.thermostat == 'nose' and dyn.tchain == 1
    assert ReversibleIsotropicNPT(hcp_copper(), DT, 300, PRESSURE, TDAMP,
                                  PDAMP, seed=1).thermostat == 'langevin'


@pytest.mark.parametrize('tchain', [1, 3])
def test_runs_back_bit_for_bit(tchain):
    atoms = hcp_copper()
    dyn = nose_npt(atoms, tchain)
    start, seen = counts(dyn), shown(atoms)
    assert {'thermostat_position', 'thermostat_momentum', 'time',
            'barostat_position', 'barostat_momentum'} <= set(start)
    dyn.run(40)
    assert not np.array_equal(atoms.positions, seen[0])
    assert dyn.thermostat_position != 1.0
    dyn.reverse().run(40)
    assert_counts_equal(dyn, start)
    assert_shown_equal(atoms, seen)
    assert dyn.get_time() == 0.0


@pytest.mark.parametrize('tchain', [1, 3])
def test_ases_mtk_assertions_hold(tchain):
    """ASE's IsotropicMTKNPT test: after 100 steps of a ``Stationary``
    start the total momentum is zero and the conserved energy changed by
    less than 1e-3 eV (measured: 1.7e-4 eV, tchain 1; 2.0e-4 eV, tchain
    3; ASE's EMT)."""
    atoms = hcp_copper()
    dyn = nose_npt(atoms, tchain)
    positions, e0 = atoms.positions.copy(), dyn.get_conserved_energy()
    dyn.run(100)
    assert np.allclose(np.sum(atoms.get_momenta(), axis=0), 0.0)
    assert np.array_equal(dyn.system.p.ints.sum(axis=0), np.zeros(3))
    assert abs(dyn.get_conserved_energy() - e0) < 1e-3
    assert not np.allclose(atoms.positions, positions)
    assert dyn.degrees_of_freedom == 3 * len(atoms) - 3


def test_a_moving_start_thermostats_3n_and_conserves_the_energy():
    atoms = hcp_copper(at_rest=False)
    dyn = nose_npt(atoms)
    assert dyn.degrees_of_freedom == 3 * len(atoms)
    e0 = dyn.get_conserved_energy()
    dyn.run(50)
    assert abs(dyn.get_conserved_energy() - e0) < 1e-3


def test_real_time_runs_at_one_over_s():
    atoms = hcp_copper()
    dyn = nose_npt(atoms)
    dyn.run(30)
    assert dyn.get_time() != 30 * DT
    assert abs(dyn.get_time() / (30 * DT) - 1.0) < 0.2


# The restarts run on ASE's EMT: asap3's stress carries the history of its
# neighbour list in its last bits, so its digest in a record differs from
# the stress a resumed run computes afresh (a MachineChangedWarning for
# either thermostat).

def test_a_trajectory_frame_resumes_the_run_bit_for_bit(tmp_path):
    path = tmp_path / 'run.traj'
    atoms = hcp_copper(calc=EMT())
    dyn = nose_npt(atoms, 3, trajectory=str(path), loginterval=10)
    dyn.run(20)
    middle = counts(dyn)
    dyn.run(20)
    whole, whole_time = shown(atoms), dyn.get_time()
    frame = read(path, index=2)
    frame.calc = EMT()
    with warnings.catch_warnings():
        warnings.simplefilter('error')
        resumed = nose_npt(frame, None)
    assert resumed.tchain == 3
    assert_counts_equal(resumed, {name: value for name, value
                                  in middle.items() if name != 'time'})
    resumed.run(20)
    assert_shown_equal(frame, whole)
    assert resumed.get_time() == whole_time
    resumed.reverse().run(40)   # back past the frame, with no buffer
    assert resumed.get_time() == 0.0
    assert np.array_equal(frame.positions, read(path, index=0).positions)


def test_two_halves_are_one_run():
    atoms = hcp_copper(calc=EMT())
    nose_npt(atoms).run(30)
    whole = shown(atoms)
    halves = hcp_copper(calc=EMT())
    nose_npt(halves).run(15)
    with warnings.catch_warnings():
        warnings.simplefilter('error')
        second = nose_npt(halves)
    second.run(15)
    assert_shown_equal(halves, whole)


def test_a_written_frame_resumes_with_its_record(tmp_path):
    atoms = hcp_copper(calc=EMT())
    dyn = nose_npt(atoms)
    dyn.run(10)
    path = tmp_path / 'frame.traj'
    write(path, atoms)
    dyn.run(10)
    frame = read(path)
    frame.calc = EMT()
    with warnings.catch_warnings():
        warnings.simplefilter('error')
        nose_npt(frame).run(10)
    assert_shown_equal(frame, shown(atoms))


def test_another_chain_than_the_records_is_refused():
    atoms = hcp_copper()
    nose_npt(atoms, 3).run(2)
    with pytest.raises(ValueError, match='tchain=3'):
        nose_npt(atoms, 1)


def test_a_langevin_run_after_a_nose_run_starts_its_own_clock():
    atoms = hcp_copper()
    nose_npt(atoms).run(10)
    with warnings.catch_warnings():
        warnings.simplefilter('error')
        dyn = ReversibleIsotropicNPT(atoms, DT, 300, PRESSURE, TDAMP, PDAMP,
                                     seed=1)
    assert dyn.get_time() == 0.0
    dyn.run(2)
    with warnings.catch_warnings():
        warnings.simplefilter('error')
        dyn = nose_npt(atoms)
    assert dyn.get_time() == 0.0 and dyn.thermostat_position == 1.0


def test_a_held_total_momentum_does_not_make_the_forces_look_changed():
    """A frame's kick digest (guarded force purity, asap3's EMT) is of the
    kick the FixCom balance left: the resumed frame's kick is balanced
    before it is compared."""
    atoms = hcp_copper(calc=needs_asap3().EMT())
    dyn = ReversibleIsotropicNPT(atoms, DT, 300, PRESSURE, TDAMP, PDAMP,
                                 seed=1)
    assert dyn.force_purity.mode == 'guarded'
    dyn.run(15)
    section = read_record(atoms.info, sections=('machine',))['machine']
    assert 'kick' in section
    assert compare(section, dyn.system) is True


@pytest.mark.parametrize('given, error, match', [
    ({'seed': 1}, TypeError, 'takes no seed'),
    ({'rng': np.random.default_rng(0)}, TypeError, 'takes no rng'),
    ({'buffer': 'x.npz'}, TypeError, 'takes no buffer'),
    ({'tloop': 2}, ValueError, 'only tloop=1'),
    ({'pchain': 3}, TypeError, 'leave pchain out'),
    ({'ploop': 1}, TypeError, 'leave ploop out'),
    ({'tchain': 0}, ValueError, 'tchain must be'),
])
def test_what_the_nose_thermostat_refuses(given, error, match):
    kwargs = {'tchain': 1, **given}
    with pytest.raises(error, match=match):
        ReversibleIsotropicNPT(hcp_copper(), DT, 300, PRESSURE, TDAMP, PDAMP,
                               thermostat='nose', **kwargs)


def test_unknown_thermostats_and_langevin_chains_are_refused():
    with pytest.raises(ValueError, match="must be one of"):
        ReversibleIsotropicNPT(hcp_copper(), DT, 300, PRESSURE, TDAMP, PDAMP,
                               thermostat='bussi')
    with pytest.raises(TypeError, match='leave tchain out'):
        ReversibleIsotropicNPT(hcp_copper(), DT, 300, PRESSURE, TDAMP, PDAMP,
                               tchain=3, seed=1)


# -- the whole cell: ReversibleNPT(..., thermostat='nose') -----------------

def cell_nose_npt(atoms, tchain=1, **kwargs):
    return ReversibleNPT(atoms, DT, 300, PRESSURE, TDAMP, PDAMP,
                         tchain=tchain, thermostat='nose', **kwargs)


@pytest.mark.parametrize('tchain', [1, 3])
def test_the_whole_cell_runs_back_and_holds_ases_mtk_assertions(tchain):
    """ASE's MTKNPT test conditions (measured: the conserved energy moved
    by 2.2e-4 eV, tchain 1, and 2.1e-4 eV, tchain 3; ASE's EMT)."""
    atoms = hcp_copper()
    dyn = cell_nose_npt(atoms, tchain)
    assert type(dyn) is ReversibleNoseNPT and dyn.thermostat == 'nose'
    assert dyn.system.g == 3 * len(atoms) - 3 + 7
    start, seen = counts(dyn), shown(atoms)
    e0 = dyn.get_conserved_energy()
    dyn.run(100)
    assert np.allclose(np.sum(atoms.get_momenta(), axis=0), 0.0)
    assert abs(dyn.get_conserved_energy() - e0) < 1e-3
    assert not np.allclose(atoms.positions, seen[0])
    assert not np.allclose(atoms.cell.array, seen[2])
    assert dyn.barostat_momentum.shape == (6,)
    dyn.reverse().run(100)
    assert_counts_equal(dyn, start)
    assert_shown_equal(atoms, seen)


def test_a_whole_cell_frame_resumes_the_run_bit_for_bit(tmp_path):
    path = tmp_path / 'cell.traj'
    atoms = hcp_copper(calc=EMT())
    dyn = cell_nose_npt(atoms, 3, trajectory=str(path), loginterval=10)
    dyn.run(30)
    whole, whole_time = shown(atoms), dyn.get_time()
    frame = read(path, index=2)
    frame.calc = EMT()
    with warnings.catch_warnings():
        warnings.simplefilter('error')
        resumed = cell_nose_npt(frame, None)
    assert type(resumed) is ReversibleNoseNPT and resumed.tchain == 3
    resumed.run(10)
    assert_shown_equal(frame, whole)
    assert resumed.get_time() == whole_time
    resumed.reverse().run(30)   # back past the frame
    assert np.array_equal(frame.positions, read(path, index=0).positions)


def test_the_whole_cells_gradients_are_refused():
    dyn = cell_nose_npt(hcp_copper())
    dyn.run(1)
    with pytest.raises(NotImplementedError, match="thermostat='langevin'"):
        dyn.backpropagate(1, grad_positions=np.ones((16, 3)))


def test_buffer_files_are_refused(tmp_path):
    dyn = nose_npt(hcp_copper())
    dyn.run(2)
    with pytest.raises(ValueError, match='no buffer'):
        dyn.write_buffer(tmp_path / 'b.npz')


class WholeRun:
    """L(x0, p0) = <a, x_T> + <b, p_T> over a fresh run of ``steps``."""

    def __init__(self, steps, tchain):
        self.steps, self.tchain = steps, tchain
        self.a_nc, self.b_nc = np.random.default_rng(5).normal(
            size=(2, 16, 3))

    def dynamics(self, dx_nc=0.0, dp_nc=0.0):
        atoms = hcp_copper(calc=EMT())
        atoms.positions = atoms.positions + dx_nc
        atoms.set_momenta(atoms.get_momenta() + dp_nc)
        # Fine quanta: a finite difference of a whole run sees the
        # rounding as noise.
        # A fast thermostat and piston: their variables move by tens of
        # per cent in the run, so that their adjoints show in the
        # gradients.
        return ReversibleIsotropicNPT(
            atoms, DT, 300, PRESSURE, 5 * units.fs, 20 * units.fs,
            tchain=self.tchain, thermostat='nose', energy_check=0,
            position_quantum=2.0**-44, momentum_quantum=2.0**-46)

    def __call__(self, dx_nc=0.0, dp_nc=0.0):
        dyn = self.dynamics(dx_nc, dp_nc)
        dyn.run(self.steps)
        return float(np.sum(self.a_nc * dyn.atoms.positions)
                     + np.sum(self.b_nc * dyn.atoms.get_momenta()))


# The single thermostat's in the quick tier, the chain's in the long one.
@pytest.mark.parametrize('tchain', tiered([1, 3], quick=[1]))
def test_gradients_match_whole_run_finite_differences(tchain):
    loss = WholeRun(steps=10, tchain=tchain)
    dyn = loss.dynamics()
    start, seen = counts(dyn), shown(dyn.atoms)
    dyn.run(loss.steps)
    grads = dyn.backpropagate(loss.steps, loss.a_nc, loss.b_nc)
    assert_counts_equal(dyn, start)   # the retrace ends at the start
    assert_shown_equal(dyn.atoms, seen)
    keys = {'lambda', 'p_lambda', 's', 'pi'} | {
        f'{v}{j}' for j in range(2, tchain + 1) for v in ('s', 'pi')}
    assert set(grads.thermostat) == keys
    u_nc, v_nc = np.random.default_rng(6).normal(size=(2, 16, 3))
    # No net momentum in the direction: the perturbed starts stay at
    # rest, as the run's (a net momentum would change N_f).
    v_nc -= v_nc.mean(axis=0)
    e = 1e-4
    zero = np.zeros((16, 3))
    for grad, dx, dp, w in ((grads.positions, u_nc, zero, u_nc),
                            (grads.momenta, zero, v_nc, v_nc)):
        fd = (loss(e * dx, e * dp) - loss(-e * dx, -e * dp)) / (2 * e)
        # Measured: within 7e-6 (positions, tchain 1); a sign flipped in
        # any one of the adjoints of the thermostat's and the piston's
        # sub-steps moves it by 1.5e-4 to 5e-3.
        assert float(np.sum(grad * w)) == pytest.approx(fd, rel=2e-5)


def test_a_retrace_in_two_segments_is_one_retrace():
    loss = WholeRun(steps=4, tchain=3)
    dyn = loss.dynamics()
    dyn.run(4)
    whole = dyn.backpropagate(4, loss.a_nc, loss.b_nc)
    dyn.run(4)
    first = dyn.backpropagate(2, loss.a_nc, loss.b_nc)
    second = dyn.backpropagate(2, first.positions, first.momenta,
                               carry=first)
    assert np.allclose(second.positions, whole.positions, rtol=1e-9,
                       atol=0)
    assert np.allclose(second.momenta, whole.momenta, rtol=1e-9, atol=0)
    for key, value in whole.thermostat.items():
        assert second.thermostat[key] == pytest.approx(value, rel=1e-9)


def liquid_argon():
    """256 Ar atoms at the liquid's density (reduced 0.73), 100 K, asap3's
    LennardJones cut at 3 sigma."""
    sigma = 3.405
    lattice = (4 / (0.73 / sigma**3)) ** (1 / 3)
    atoms = bulk('Ar', 'fcc', a=lattice, cubic=True) * (4, 4, 4)
    atoms.calc = needs_asap3().LennardJones(
        [18], [0.0103], [sigma], rCut=3 * sigma, modified=True)
    thermalize_momenta(atoms, 100, rng=np.random.default_rng(1))
    Stationary(atoms)
    return atoms


@SLOW
def test_the_ensemble_is_the_langevin_barostats():
    """Mean volume and temperature of liquid argon at 100 K and 50 bar
    (10 fs, tdamp 100 steps, pdamp 1000 steps, 2,000 steps left out, then
    10,000 sampled every 10), Nosé's chain of 3 against the Langevin
    thermostat: the same within the runs' errors (docs/pressure.md,
    "A check of the ensemble with Nosé's thermostat")."""
    dt = 10 * units.fs
    means = {}
    for thermostat, kwargs in (('langevin', {'seed': 1}),
                               ('nose', {'tchain': 3})):
        atoms = liquid_argon()
        dyn = ReversibleIsotropicNPT(
            atoms, dt, 100, 50 * units.bar, 100 * dt, 1000 * dt,
            thermostat=thermostat, force_noise=3.4e-13, **kwargs)
        dyn.run(2000)
        volumes, temperatures = [], []
        for _ in range(1000):
            dyn.run(10)
            volumes.append(atoms.get_volume() / len(atoms))
            temperatures.append(atoms.get_kinetic_energy() / (
                1.5 * units.kB * (len(atoms) - 1)))
        means[thermostat] = (np.mean(volumes), np.mean(temperatures))
    (v_l, t_l), (v_n, t_n) = means['langevin'], means['nose']
    # Errors of such runs (20 blocks): 0.3 Å**3 an atom, 0.5 K.
    assert abs(v_n - v_l) < 1.2, means
    assert abs(t_n - 100) < 2 and abs(t_l - 100) < 2, means
