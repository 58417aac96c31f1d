"""ReversibleLangevin: exact reversal of thermostatted runs, and its contract.

Every reversal case compares positions and momenta with np.array_equal
against the state right after the constructor, checks the run went
somewhere, and that the information buffer is empty again.
"""

import numpy as np
import pytest
from ase import units
from ase.constraints import FixAtoms, FixCartesian, FixedPlane
from ase.io import read

from ase_reversible import (AnchorMovedWarning, ReversibleLangevin,
                            UnsupportedConstraintError)

from conftest import CALCULATORS, THERMOSTAT_CASES, argon_bulk
from exactness import (assert_runs_back, assert_same_state, forward_and_back,
                       snapshot)
from thermostats import FRICTION, ar13, assert_buffers_empty, langevin
from tiers import tiered


@pytest.mark.parametrize('fixcm', tiered([True, False], quick=[True]))
@pytest.mark.parametrize('case', list(THERMOSTAT_CASES))
def test_round_trip_is_exact(case, fixcm):
    build, calc, dt_fs, steps = THERMOSTAT_CASES[case]
    atoms = build()
    atoms.calc = CALCULATORS[calc]()
    dyn = langevin(atoms, dt_fs, fixcm=fixcm)
    assert_runs_back(dyn, steps)
    assert_buffers_empty(dyn)
    assert dyn.get_time() == 0.0


@pytest.mark.parametrize('constraint', ['FixAtoms', 'FixCartesian'])
def test_constrained_coordinates_stay_put_and_reversal_is_exact(constraint):
    atoms = ar13()
    if constraint == 'FixAtoms':
        atoms.set_constraint(FixAtoms(indices=[0, 5]))
        frozen = np.zeros((len(atoms), 3), bool)
        frozen[[0, 5]] = True
    else:
        atoms.set_constraint(FixCartesian(3, mask=(True, False, True)))
        frozen = np.zeros((len(atoms), 3), bool)
        frozen[3, [0, 2]] = True
    dyn = langevin(atoms)
    x0 = atoms.get_positions()  # on the grid
    dyn.run(200)
    assert np.array_equal(atoms.positions[frozen], x0[frozen])
    assert not np.any(atoms.get_momenta()[frozen])
    assert not np.array_equal(atoms.positions[~frozen], x0[~frozen])
    start = (x0, np.zeros_like(x0))
    dyn.reverse()
    dyn.run(200)
    assert np.array_equal(atoms.positions, start[0])
    assert_buffers_empty(dyn)


def test_a_plane_constraint_is_refused_and_nothing_changes():
    atoms = ar13()
    atoms.set_constraint(FixedPlane(0, (0, 0, 1)))
    before = snapshot(atoms)
    with pytest.raises(UnsupportedConstraintError,
                       match='FixAtoms, FixCartesian and FixCom.*'
                       'ReversibleNose.*ReversibleVerlet'):
        langevin(atoms)
    assert_same_state(atoms, before)


def test_a_plane_set_between_runs_is_refused_and_the_run_goes_on():
    atoms = ar13()
    dyn = langevin(atoms)
    dyn.run(10)
    here = snapshot(atoms)
    atoms.set_constraint(FixedPlane(0, (0, 0, 1)))
    with pytest.raises(UnsupportedConstraintError, match='FixedPlane'):
        dyn.run(5)
    assert_same_state(atoms, here)
    del atoms.constraints
    dyn.reverse().run(10)  # the run was not re-anchored: back to the start
    assert dyn.engine.steps_since_anchor == 0


def test_a_default_seed_is_drawn_kept_and_resumed_from_the_record():
    seeds = []
    for _ in range(2):
        atoms = ar13()
        dyn = ReversibleLangevin(atoms, units.fs, 300, FRICTION)
        seeds.append(dyn.seed)
        assert dyn.todict()['seed'] == dyn.seed
    assert isinstance(seeds[0], int) and seeds[0] != seeds[1]
    # The atoms now carry the record: a new integrator goes on with it.
    assert ReversibleLangevin(atoms, units.fs, 300, FRICTION).seed == seeds[1]


@pytest.mark.parametrize('kwargs, error, match', [
    ({'rng': np.random.default_rng(0)}, ValueError, 'both seed=1 and rng'),
    ({'rng': 7, 'seed': None}, TypeError, 'pass seed= instead'),
    ({'temperature_K': 0}, ValueError, 'temperature_K must be positive'),
    ({'friction': -1.0}, ValueError, 'friction must be positive'),
    ({'friction': 100.0}, ValueError, 'at most'),
    ({'friction': 1e-18}, ValueError, 'pass friction=0'),
    ({'friction': 'none'}, TypeError, 'friction must be a number'),
    ({'seed': 1.5}, TypeError, 'seed must be an int'),
])
def test_bad_arguments_are_refused_before_anything_changes(kwargs, error,
                                                          match):
    atoms = ar13()
    before = snapshot(atoms)
    arguments = {'timestep': 5 * units.fs, 'temperature_K': 300,
                 'friction': FRICTION, 'seed': 1, **kwargs}
    with pytest.raises(error, match=match):
        ReversibleLangevin(atoms, **arguments)
    assert_same_state(atoms, before)


def test_zero_friction_is_constant_energy_with_an_empty_buffer():
    atoms = ar13()
    dyn = ReversibleLangevin(atoms, 5 * units.fs, 300, friction=0, seed=1)
    assert dyn.friction == 0 and dyn.effective_friction == 0
    energy = atoms.get_total_energy()
    start = snapshot(atoms)
    dyn.run(200)
    # No thermostat: the energy stays put but for the time-step error
    # (measured 2.4e-6 eV here; 0.50 eV with friction 0.02 / fs), and
    # nothing is stored or added.
    assert abs(atoms.get_total_energy() - energy) < 1e-3
    assert not dyn.friction_step.buffers and dyn.buffer_bits == 0
    assert dyn.heat == 0.0
    dyn.reverse().run(200)
    assert_same_state(atoms, start)
    # Nothing to undo: it runs back past its start, and forward again.
    dyn.run(20)
    dyn.reverse().run(20)
    assert_same_state(atoms, start)


def test_friction_set_to_zero_and_back_mid_run():
    atoms = ar13()
    dyn = langevin(atoms)
    dyn.run(20)
    with pytest.warns(AnchorMovedWarning, match='friction'):
        dyn.set_friction(0.0)
    here = snapshot(atoms)
    dyn.run(30)
    dyn.reverse().run(30)
    assert_same_state(atoms, here)
    dyn.reverse()
    dyn.set_friction(FRICTION)
    dyn.run(10)
    assert dyn.buffer_bits > 0


def test_a_new_friction_is_taken_like_a_new_temperature():
    atoms = ar13()
    dyn = langevin(atoms)
    dyn.run(20)
    with pytest.warns(AnchorMovedWarning, match='friction'):
        dyn.set_friction(0.05 / units.fs)
    here = snapshot(atoms)
    forward_and_back(dyn, 30)
    assert_same_state(atoms, here)
    assert dyn.effective_friction == pytest.approx(0.05 / units.fs,
                                                   rel=1e-3)


def test_the_thermostat_holds_the_temperature():
    """Argon at 80 K started at 10 K: after 1 ps the mean kinetic
    temperature over 4 ps is within 2% of 80 K times (3N - 3) / 3N (the
    noise carries no net momentum).  Its statistical error here is about
    0.3%."""
    atoms = argon_bulk((2, 2, 2), 10)
    atoms.calc = CALCULATORS['ase-lj']()
    dyn = langevin(atoms, 10, temperature_K=80)
    temperatures = []
    dyn.attach(lambda: temperatures.append(atoms.get_temperature()))
    dyn.run(500)
    n = len(atoms)
    assert np.mean(temperatures[100:]) == pytest.approx(
        80 * (3 * n - 3) / (3 * n), rel=0.02)


# -- restarts -----------------------------------------------------------------



# -- gradients ---------------------------------------------------------------

def test_gradients_match_complex_step_through_a_float_baoab_run():
    """backpropagate against complex-step differentiation of a plain float
    BAOAB run written here, with the same friction ratio and the same noise
    integers, for the initial state and the potential's epsilon and sigma.
    The fixed-point friction rounds to within n = c 2**16 momentum quanta
    per step, so the two paths part by more than NVE's: measured relative
    errors 8e-10 to 7.2e-9 for the state, 2.4e-9 (epsilon) and 8.4e-12
    (sigma); without the friction's adjoint (a_p *= c, c = 0.905) they
    would be of order one."""
    from ase_reversible.core.infobuffer import friction_ratio
    from ase_reversible.core.noise import StepNoise, step_key
    from finite_differences import (argon_lj_forces, complex_step_errors,
                                    float_kick_drift_run)
    from test_adjoint import FINE, argon, random_loss

    steps, dt, temperature = 150, 5 * units.fs, 60.0
    atoms = argon(2, 40, rc=30.0, ro=29.0)
    a_nc, b_nc = random_loss(atoms)
    dyn = ReversibleLangevin(atoms, dt, temperature, FRICTION, fixcm=False,
                             seed=2, energy_check=0, **FINE)
    x0_nc, p0_nc = atoms.positions.copy(), atoms.get_momenta()
    dyn.run(steps)
    g = dyn.backpropagate(steps, a_nc, b_nc,
                          parameters=('epsilon', 'sigma'))
    assert np.array_equal(atoms.positions, x0_nc)

    m_n1 = atoms.get_masses()[:, None]
    potential, forces = argon_lj_forces()
    qp = dyn.grid.momentum_quantum
    ratio = friction_ratio(np.exp(-FRICTION * dt)) / 2**16
    sigma_nc = np.sqrt((1 - ratio**2) * m_n1 * units.kB * temperature) / qp \
        * np.ones((1, 3))
    draw, key = StepNoise(x0_nc.size), step_key(2, dt)
    noise = [np.rint(sigma_nc * draw.normals(key, k).reshape(-1, 3)) * qp
             for k in range(steps)]

    def loss_imag(x_nc, p_nc):
        x_nc, p_nc = float_kick_drift_run(
            x_nc, p_nc, m_n1, dt, steps, forces,
            lambda k, p_nc: ratio * p_nc + noise[k])
        return np.vdot(a_nc, x_nc.imag) + np.vdot(b_nc, p_nc.imag)

    errors = complex_step_errors(loss_imag, x0_nc, p0_nc, g, potential)
    assert max(errors) < 1e-7, errors
