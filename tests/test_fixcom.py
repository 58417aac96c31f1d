"""FixCom with every integrator: the centre of mass held on the integers.

What is held exactly, and tested here with whole numbers (never a
tolerance): the momentum counts sum to zero in each Cartesian component
after every step; with equal masses the position counts' sum never
changes (the centre of mass is exactly fixed); with unequal masses each
drift moves the centre of mass by at most half a position quantum,
computed in exact rational arithmetic.  Every run also comes back bit
for bit.
"""

import warnings
from fractions import Fraction

import numpy as np
import pytest
from ase import units
from ase.calculators.emt import EMT
from ase.constraints import FixAtoms, FixCartesian, FixCom
from ase.io import Trajectory, read

from ase_reversible import (AnchorMovedWarning, ReversibleLangevin,
                            ReversibleNose, ReversibleVerlet)
from ase_reversible.md.constraints import FixedCentre

from conftest import DT, copper_bulk, copper_cluster
from exactness import assert_same_state, snapshot
from tiers import SLOW

INTEGRATORS = {
    'verlet': lambda atoms: ReversibleVerlet(atoms, DT),
    'verlet-position': lambda atoms: ReversibleVerlet(atoms, DT,
                                                      scheme='position'),
    'verlet-4': lambda atoms: ReversibleVerlet(atoms, DT, order=4),
    'verlet-4-position': lambda atoms: ReversibleVerlet(
        atoms, DT, order=4, scheme='position'),
    'langevin': lambda atoms: ReversibleLangevin(
        atoms, DT, 600, 0.02 / units.fs, seed=3),
    'langevin-fixcm-false': lambda atoms: ReversibleLangevin(
        atoms, DT, 600, 0.02 / units.fs, fixcm=False, seed=3),
    'nose': lambda atoms: ReversibleNose(atoms, DT, 600, 20 * DT),
}


def cu32(gold=0, push=(0.0, 0.0, 0.0)):
    """Periodic Cu32 at 600 K (ASE EMT), its first ``gold`` atoms made Au,
    every atom given the extra momentum ``push`` (amu Å / ASE time)."""
    atoms = copper_bulk((2, 2, 2), 600, seed=1)
    atoms.symbols[:gold] = 'Au'
    atoms.set_momenta(atoms.get_momenta() + push)
    atoms.calc = EMT()
    return atoms


def mass_moment(dyn):
    """``sum_i m_i ix_i`` per component, exactly (Fractions)."""
    masses = [Fraction(float(m)) for m in dyn.system.m_n1[:, 0]]
    ix_nc = dyn.state.ix_nc
    return [sum(m * int(x) for m, x in zip(masses, ix_nc[:, c]))
            for c in range(3)]


def drifts_per_step(dyn):
    return sum(1 for substep, _ in dyn.engine.plan
               if substep is dyn.system.drift)


class Held:
    """An observer that checks, after every step, what FixCom holds."""

    def __init__(self, dyn):
        self.dyn = dyn
        self.total_mass = Fraction(float(dyn.system.m_n1.sum()))
        self.moment = mass_moment(dyn)
        self.position_sum = dyn.state.ix_nc.sum(axis=0)
        self.equal = dyn.system.centre.equal_masses
        self.bound = Fraction(drifts_per_step(dyn), 2)
        self.steps = self.largest_move = 0

    def __call__(self):
        state = self.dyn.state
        assert not state.ip_nc.sum(axis=0).any()
        if self.equal:
            assert np.array_equal(state.ix_nc.sum(axis=0), self.position_sum)
        moment = mass_moment(self.dyn)
        for before, after in zip(self.moment, moment):
            move = abs(after - before) / self.total_mass  # position quanta
            self.largest_move = max(self.largest_move, move)
            assert move <= self.bound * (1 + Fraction(1, 2**40))
        self.moment = moment
        self.steps += 1


def out_and_back(dyn, steps):
    """Check what is held at every step out and back; the atoms must have
    moved and come back bit for bit."""
    start = snapshot(dyn.atoms)
    first = dyn.nsteps == 0  # the first run calls observers at its start
    held = Held(dyn)
    dyn.attach(held)
    dyn.run(steps)
    assert not np.array_equal(dyn.atoms.positions, start[0])
    dyn.reverse().run(steps)
    assert_same_state(dyn.atoms, start)
    assert held.steps == 2 * steps + first
    return held


@pytest.mark.parametrize('name', sorted(INTEGRATORS))
def test_equal_masses_hold_the_centre_of_mass_exactly(name):
    atoms = cu32()
    atoms.set_constraint(FixCom())
    dyn = INTEGRATORS[name](atoms)
    assert dyn.system.centre.equal_masses
    held = out_and_back(dyn, 12)
    assert held.largest_move == 0


@pytest.mark.parametrize('name', sorted(INTEGRATORS))
def test_unequal_masses_hold_the_momentum_exactly(name):
    atoms = cu32(gold=5)
    atoms.set_constraint(FixCom())
    dyn = INTEGRATORS[name](atoms)
    assert not dyn.system.centre.equal_masses
    held = out_and_back(dyn, 12)
    assert held.largest_move > 0  # the bound, not a constant, is held


@pytest.mark.parametrize('name', ['verlet', 'langevin', 'nose'])
def test_unwatched_runs_end_with_zero_total_momentum(name):
    # A run with no observer takes the loop that shows the state only at
    # its end.
    atoms = cu32()
    atoms.set_constraint(FixCom())
    dyn = INTEGRATORS[name](atoms)
    start, position_sum = snapshot(atoms), dyn.state.ix_nc.sum(axis=0)
    dyn.run(15)
    assert not dyn.state.ip_nc.sum(axis=0).any()
    assert np.array_equal(dyn.state.ix_nc.sum(axis=0), position_sum)
    dyn.reverse().run(15)
    assert_same_state(atoms, start)


@pytest.mark.parametrize('name', ['verlet', 'langevin', 'nose'])
def test_with_fixed_atoms_and_components(name):
    atoms = cu32()
    atoms.set_constraint([FixAtoms([0, 7]), FixCartesian(3, (False, True,
                                                            False)),
                          FixCom()])
    dyn = INTEGRATORS[name](atoms)
    x0 = atoms.positions.copy()  # snapped to the grid
    # The projected start: fixed momenta zero, the rest summing to zero.
    assert not dyn.state.ip_nc[[0, 7]].any()
    assert dyn.state.ip_nc[3, 1] == 0
    out_and_back(dyn, 10)
    dyn.reverse().run(10)
    assert np.array_equal(atoms.positions[[0, 7]], x0[[0, 7]])
    assert atoms.positions[3, 1] == x0[3, 1]


@pytest.mark.parametrize('gold', [0, 5])
def test_the_constructor_removes_a_net_momentum_on_the_grid(gold):
    atoms = cu32(gold, push=(2.0, -1.0, 0.5))
    expected = atoms.get_momenta()
    FixCom().adjust_momenta(atoms, expected)  # what ASE's FixCom does
    atoms.set_constraint(FixCom())
    dyn = ReversibleVerlet(atoms, DT)
    q = dyn.grid.momentum_quantum
    assert not dyn.state.ip_nc.sum(axis=0).any()
    # On the grid: within rounding (half a quantum) plus the balance's
    # rounding of each share and its one count.
    assert np.abs(atoms.get_momenta() - expected).max() <= 2 * q


def test_nose_counts_three_fewer_degrees_of_freedom():
    atoms = cu32()
    atoms.set_constraint(FixCom())
    assert ReversibleNose(atoms, DT, 600, 20 * DT).degrees_of_freedom \
        == 3 * 32 - 3
    atoms = cu32()
    atoms.set_constraint([FixAtoms([0, 1]), FixCom()])
    assert ReversibleNose(atoms, DT, 600, 20 * DT).degrees_of_freedom \
        == 3 * 30 - 3


def test_nose_with_fixcom_does_not_warn_about_a_moving_centre():
    atoms = cu32(push=(3.0, 0.0, 0.0))
    atoms.set_constraint(FixCom())
    with warnings.catch_warnings():
        warnings.simplefilter('error', UserWarning)
        dyn = ReversibleNose(atoms, DT, 600, 20 * DT)
    assert not dyn.state.ip_nc.sum(axis=0).any()


@pytest.mark.parametrize('name', ['verlet-4', 'langevin', 'nose'])
def test_a_trajectory_frame_resumes_bit_for_bit(tmp_path, name):
    atoms = cu32(gold=3)
    atoms.set_constraint(FixCom())
    dyn = INTEGRATORS[name](atoms)
    dyn.run(5)
    with Trajectory(tmp_path / 'run.traj', 'w') as traj:
        traj.write(atoms)
    extra = {}
    if name == 'langevin':  # its friction's digits go with the frame
        dyn.write_buffer(tmp_path / 'buffer.npz')
        extra['buffer'] = tmp_path / 'buffer.npz'
    dyn.run(10)
    reference = snapshot(atoms)
    frame = read(tmp_path / 'run.traj')
    assert any(isinstance(c, FixCom) for c in frame.constraints)
    frame.calc = EMT()
    resumed = INTEGRATORS[name](frame) if not extra else ReversibleLangevin(
        frame, DT, 600, 0.02 / units.fs, seed=3, **extra)
    held = Held(resumed)
    resumed.attach(held)
    resumed.run(10)
    assert_same_state(frame, reference)
    assert held.steps == 11


def test_fixcom_set_between_runs_is_taken_with_zero_total_momentum():
    atoms = cu32(push=(1.0, 0.0, 0.0))
    dyn = ReversibleVerlet(atoms, DT)
    dyn.run(3)
    assert dyn.state.ip_nc.sum(axis=0)[0] != 0
    atoms.set_constraint(FixCom())
    with pytest.warns(AnchorMovedWarning, match='constraints'):
        dyn.run(0)
    out_and_back(dyn, 8)


def test_a_cluster_with_asap3_if_installed():
    from conftest import asap_emt
    atoms = copper_cluster(3, 600, seed=2)
    atoms.calc = asap_emt()
    atoms.set_constraint(FixCom())
    out_and_back(ReversibleVerlet(atoms, DT), 20)


def test_the_balance_is_odd_and_sums_to_zero():
    rng = np.random.default_rng(5)
    masses = rng.choice([1.008, 12.011, 63.546, 196.97], size=40)
    free = np.ones((40, 3))
    free[[2, 9], :] = 0
    free[11, 1] = 0
    centre = FixedCentre(masses, free)
    for scale in (0.4, 3.0, 1e4, 1e12):
        r = np.rint(rng.normal(scale=scale, size=(40, 3))) * free
        up, down = r.copy(), -r
        centre.balance(up)
        centre.balance(down)
        assert np.array_equal(down, -up)
        assert not up.sum(axis=0).any()
        assert not up[free == 0].any()
        # Each atom gets its share of the sum, rounded, and at most one
        # count of what the rounding left.
        share = np.rint(centre.weights_nc * r.sum(axis=0))
        assert np.abs(r - up - share).max() <= 1


@pytest.mark.parametrize('mixed', [False, True])
def test_gradients_match_whole_run_finite_differences(mixed):
    # The kick's balance is f_i - w_i sum_j f_j up to rounding: its
    # transpose is pulled back, and the constructor's removal of a net
    # momentum is part of the run the gradient of the momenta is of.
    from test_adjoint import WholeRun, argon, random_loss, relative_error

    def build():
        atoms = argon(2, 40)
        if mixed:
            atoms.symbols[:3] = 'Kr'
        atoms.set_constraint([FixAtoms([4]), FixCom()])
        return atoms

    a_nc, b_nc = random_loss(build())
    run = WholeRun(build, 100, a_nc, b_nc)
    g = run.gradients()
    rng = np.random.default_rng(3)
    u_nc, v_nc = rng.normal(size=(2,) + a_nc.shape)
    h = 1e-6
    fd_x = (run(dx_nc=h * u_nc) - run(dx_nc=-h * u_nc)) / (2 * h)
    fd_p = (run(dp_nc=h * v_nc) - run(dp_nc=-h * v_nc)) / (2 * h)
    assert relative_error(np.vdot(g.positions, u_nc), fd_x) < 1e-5
    assert relative_error(np.vdot(g.momenta, v_nc), fd_p) < 1e-5


@SLOW
def test_the_balance_gives_the_same_bits_on_other_machines(tmp_path):
    # Its sums over atoms are matrix-vector products, whose kernels differ
    # between CPUs; on whole numbers below 2**53 every order is exact.
    from machines import run_leg
    script = (
        'import numpy as np\n'
        'from ase_reversible.md.constraints import FixedCentre\n'
        'rng = np.random.default_rng(11)\n'
        'masses = rng.choice([1.008, 63.546, 196.97], size=300)\n'
        'free = np.ones((300, 3)); free[5] = 0\n'
        'out = []\n'
        'for m, f in ((masses, free), (np.full(300, 39.948), free * 0 + 1)):\n'
        '    centre = FixedCentre(m, f)\n'
        '    for scale in (0.4, 1e3, 1e13):\n'
        '        r = np.rint(rng.normal(scale=scale, size=(300, 3)))\n'
        '        r *= centre.free_nc\n'
        '        centre.balance(r)\n'
        '        out.append(r.tobytes().hex())\n'
        'print(" ".join(out))\n'
        'print((np.ones(300) @ rng.uniform(0.5, 3.0, (300, 3))).tobytes())\n')
    native, sse4 = (run_leg(machine, script, tmp_path).splitlines()
                    for machine in ('native', 'sse4'))
    assert native[0] == sse4[0] and len(native[0].split()) == 6
    # The same product of fractional numbers does differ: the emulated
    # machine runs another kernel.
    assert native[1] != sse4[1]


@pytest.mark.parametrize('name', ['verlet-position', 'langevin', 'nose'])
def test_backpropagate_retraces_exactly(name):
    atoms = cu32(gold=3)
    atoms.set_constraint(FixCom())
    dyn = INTEGRATORS[name](atoms)
    start = snapshot(atoms)
    dyn.run(8)
    end = snapshot(atoms)
    a_nc, b_nc = np.random.default_rng(4).normal(size=(2, 32, 3))
    g = dyn.backpropagate(8, a_nc, b_nc)
    assert_same_state(atoms, start)
    # The momenta's gradient is pulled back through the removal of a net
    # momentum: its mass-weighted sum is zero (to rounding).
    weights = dyn.system.centre.weights_nc
    assert np.abs(np.einsum('nc,nc->c', weights, g.momenta)).max() < 1e-9 \
        * np.abs(g.momenta).max()
    dyn.run(8)
    assert_same_state(atoms, end)


def test_refusals_name_what_takes_the_constraints():
    from ase.constraints import FixedPlane
    from ase_reversible import UnsupportedConstraintError
    plane = FixedPlane([1, 2], (1.0, 2.0, 3.0))
    atoms = cu32()
    atoms.set_constraint([plane, FixCom()])
    before = snapshot(atoms)
    with pytest.raises(UnsupportedConstraintError,
                       match='ReversibleNose.*ReversibleVerlet.*without '
                             'FixCom.*Stationary'):
        INTEGRATORS['langevin'](atoms)
    with pytest.raises(UnsupportedConstraintError,
                       match='^FixedPlane together with FixCom.*'
                             'FixCartesian.*Stationary'):
        INTEGRATORS['nose'](atoms)
    assert_same_state(atoms, before)
    # What the messages point to is taken, and runs back exactly.
    atoms.set_constraint(plane)
    dyn = INTEGRATORS['nose'](atoms)
    start = snapshot(atoms)
    dyn.run(5)
    dyn.reverse().run(5)
    assert_same_state(atoms, start)


@pytest.mark.slow
@pytest.mark.parametrize('name', ['verlet-4', 'langevin', 'nose'])
def test_long_runs_of_cu108_with_asap3(name):
    from conftest import asap_emt
    atoms = copper_bulk((3, 3, 3), 600, seed=4)
    atoms.symbols[:10] = 'Au'
    atoms.calc = asap_emt()
    atoms.set_constraint(FixCom())
    dyn = INTEGRATORS[name](atoms)
    start = snapshot(atoms)
    dyn.run(1000)
    assert not dyn.state.ip_nc.sum(axis=0).any()
    dyn.reverse().run(1000)
    assert_same_state(atoms, start)
