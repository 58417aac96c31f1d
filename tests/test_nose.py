"""ReversibleNose: exact reversal of a deterministic NVT, and its contract.

Every reversal case compares every exact variable -- positions, virtual
momenta, the thermostat's s and pi, the real-time clock -- with
np.array_equal against the counts right after the constructor, and checks
that the run went somewhere.
"""

import warnings

import numpy as np
import pytest
from ase import units
from ase.constraints import FixAtoms, FixCartesian, FixCom, FixedPlane
from ase.io import Trajectory, read
from ase.md.velocitydistribution import Stationary

from ase_reversible import (AnchorMovedWarning, ReversibleNose,
                            UnsupportedConstraintError)

from conftest import (AR_EPSILON, AR_SIGMA, CALCULATORS, THERMOSTAT_CASES,
                      argon_bulk, argon_cluster)
from exactness import assert_same_state, snapshot
from tiers import SLOW

TDAMP = 100 * units.fs


def nose(atoms, dt_fs=5, temperature_K=300, **kwargs):
    return ReversibleNose(atoms, dt_fs * units.fs, temperature_K, TDAMP,
                          **kwargs)


def ar13():
    """Ar13 at 60 K with ASE's Lennard-Jones, at rest as a whole."""
    atoms = argon_cluster(2, 60)
    Stationary(atoms)
    atoms.calc = CALCULATORS['ase-lj']()
    return atoms


def assert_same_counts(a, b):
    assert a.keys() == b.keys()
    for name in a:
        assert np.array_equal(a[name], b[name]), name


def assert_counts_run_back(dyn, steps):
    """From here, ``steps`` out and back: every exact variable as it was."""
    here = dyn.counts
    dyn.run(steps)
    dyn.reverse().run(steps)
    assert_same_counts(dyn.counts, here)


def assert_thermostat_moved(dyn, start):
    for name in ('position', 'momentum', 'thermostat_position',
                 'thermostat_momentum', 'time'):
        assert not np.array_equal(dyn.counts[name], start[name]), name


@pytest.mark.parametrize('case', list(THERMOSTAT_CASES))
def test_round_trip_is_exact(case):
    build, calc, dt_fs, steps = THERMOSTAT_CASES[case]
    atoms = build()
    Stationary(atoms)
    atoms.calc = CALCULATORS[calc]()
    # Near what equipartition leaves of the temperature the momenta were
    # drawn at (half, on a lattice): s stays near 1, so the real time
    # step stays near dt (see docs/thermostats.md, "Start near
    # equilibrium").
    dyn = nose(atoms, dt_fs, temperature_K=0.6 * atoms.get_temperature())
    start, shown = dyn.counts, snapshot(atoms)
    dyn.run(steps)
    assert_thermostat_moved(dyn, start)
    dyn.reverse()
    dyn.run(steps)
    assert_same_counts(dyn.counts, start)
    assert_same_state(atoms, shown)
    assert dyn.get_time() == 0.0


@pytest.mark.parametrize('constraint, free', [
    (FixAtoms(indices=[0, 5]), 3 * 11),
    (FixCartesian(3, mask=(True, False, True)), 3 * 13 - 2),
    (FixedPlane(0, (0, 0, 1)), 3 * 13 - 1),
])
def test_constraints_set_the_degrees_of_freedom_and_reversal_is_exact(
        constraint, free):
    atoms = ar13()
    atoms.set_constraint(constraint)
    dyn = nose(atoms)
    assert dyn.degrees_of_freedom == free
    assert dyn.system.g == free + 1
    start = dyn.counts
    dyn.run(200)
    assert_thermostat_moved(dyn, start)
    dyn.reverse().run(200)
    assert_same_counts(dyn.counts, start)


def test_free_atoms_count_3n_as_ases_and_3n_minus_3_with_fixcom():
    atoms = ar13()
    assert nose(atoms).degrees_of_freedom == 3 * 13
    atoms = ar13()
    atoms.set_constraint(FixCom())
    assert nose(atoms).degrees_of_freedom == 3 * 13 - 3


def test_the_atoms_show_the_real_momenta_and_the_clock_real_time():
    atoms = ar13()
    dyn = nose(atoms, temperature_K=200)
    steps = []
    dyn.attach(lambda: steps.append((dyn.thermostat_position,
                                     dyn.get_time())))
    dyn.run(100)
    s = dyn.thermostat_position
    assert s != 1.0
    virtual = dyn.counts['momentum'] * dyn.grid.momentum_quantum
    assert np.array_equal(atoms.get_momenta(), virtual / s)
    # Each step advances real time by about dt / s.
    (_, t0), (s1, t1) = steps[-2], steps[-1]
    assert t1 - t0 == pytest.approx(5 * units.fs / s1, rel=0.01)


def test_extended_energy_is_conserved_while_the_atoms_heat_up():
    atoms = argon_cluster(3, 20)
    Stationary(atoms)
    atoms.calc = CALCULATORS['ase-lj']()
    dyn = nose(atoms, temperature_K=60)
    e0, k0 = dyn.get_conserved_energy(), atoms.get_kinetic_energy()
    dyn.run(400)
    heated = atoms.get_kinetic_energy() - k0
    drift = dyn.get_conserved_energy() - e0
    assert heated > 0.05  # the thermostat heated the cluster
    assert abs(drift) < 1e-2 * heated


@SLOW
def test_the_thermostat_holds_the_temperature():
    """Argon drawn at 160 K on its lattice (equipartition leaves about
    80 K), at rest as a whole, thermostatted at 80 K: the mean kinetic
    temperature over ASE's 3N (``atoms.get_temperature()``, which the
    thermostat holds) over steps 200 to 2000 (18 ps) is within 2% of 80 K.
    Measured: 79.98 K; the internal motion's, over 3N - 3, 82.56 K (3N /
    (3N - 3) above, as ASE's NoseHooverChainNVT leaves it)."""
    atoms = argon_bulk((2, 2, 2), 160)
    Stationary(atoms)
    atoms.calc = CALCULATORS['ase-lj']()
    dyn = ReversibleNose(atoms, 10 * units.fs, 80, 100 * units.fs)
    n = len(atoms)
    kinetic = []
    dyn.attach(lambda: kinetic.append(atoms.get_kinetic_energy()))
    dyn.run(2000)
    temperature = 2 * np.mean(kinetic[200:]) / (3 * n * units.kB)
    assert temperature == pytest.approx(80, rel=0.02)


def test_a_frame_with_edited_momenta_is_a_quiet_new_start(tmp_path):
    # As for every dynamics: the thermostat starts afresh (s = 1, pi = 0),
    # the clock at 0, nothing said; and the new run goes back exactly.
    traj = tmp_path / 'md.traj'
    atoms = ar13()
    dyn = nose(atoms, trajectory=str(traj))
    dyn.run(20)
    dyn.close()
    frame = read(str(traj), -1)
    frame.calc = CALCULATORS['ase-lj']()
    frame.set_momenta(frame.get_momenta() * 1.01)
    with warnings.catch_warnings():
        warnings.simplefilter('error', AnchorMovedWarning)
        resumed = nose(frame)
    assert resumed.get_time() == 0.0
    assert resumed.thermostat_position == 1.0
    assert resumed.thermostat_momentum == 0.0
    assert_counts_run_back(resumed, 30)


def test_momenta_edited_between_runs_are_taken_as_real_momenta():
    atoms = ar13()
    dyn = nose(atoms, temperature_K=200)
    dyn.run(50)
    s = dyn.thermostat_position
    cooler = 0.5 * atoms.get_momenta()
    atoms.set_momenta(cooler)
    with pytest.warns(AnchorMovedWarning, match='changed outside'):
        dyn.run(0)
    # Snapped: p' = s p to the grid, shown as p' / s.
    assert np.allclose(atoms.get_momenta(), cooler, rtol=0,
                       atol=dyn.grid.momentum_quantum)
    assert dyn.thermostat_position == s
    assert_counts_run_back(dyn, 30)


def test_a_new_temperature_moves_the_anchor_and_reversal_leads_there():
    atoms = ar13()
    dyn = nose(atoms)
    dyn.run(40)
    with pytest.warns(AnchorMovedWarning, match='temperature'):
        dyn.set_temperature(500)
    assert dyn.temperature_K == 500
    here = dyn.counts
    dyn.run(40)
    dyn.reverse()
    with warnings.catch_warnings():
        warnings.simplefilter('error', AnchorMovedWarning)
        dyn.run(40)
    assert_same_counts(dyn.counts, here)


def test_trajectory_and_log_work_as_for_ase(tmp_path):
    atoms = ar13()
    log, traj = tmp_path / 'md.log', tmp_path / 'md.traj'
    dyn = nose(atoms, trajectory=str(traj), logfile=str(log),
               loginterval=10)
    dyn.run(50)
    dyn.close()
    frames = read(str(traj), ':')
    assert len(frames) == 6
    assert np.array_equal(frames[-1].get_momenta(), atoms.get_momenta())
    assert len(log.read_text().splitlines()) == 7
    with Trajectory(str(traj)) as t:
        assert t.description['tdamp'] == TDAMP


@pytest.mark.parametrize('kwargs, error, match', [
    ({'temperature_K': 0}, ValueError, 'temperature_K must be positive'),
    ({'temperature_K': float('nan')}, ValueError, 'temperature_K must be'),
    ({'tdamp': -1.0}, ValueError, 'tdamp must be positive'),
    ({'tdamp': 'long'}, TypeError, 'tdamp must be a number'),
    ({'tloop': 2}, ValueError, 'accepts only tloop=1'),
    ({'tchain': 0}, ValueError, 'tchain must be a whole number'),
    ({'tchain': 2.0}, ValueError, 'tchain must be a whole number'),
    ({'scheme': 'leapfrog'}, ValueError, 'scheme must be one of'),
])
def test_bad_arguments_are_refused_before_anything_changes(kwargs, error,
                                                          match):
    atoms = ar13()
    before = snapshot(atoms)
    arguments = {'timestep': 5 * units.fs, 'temperature_K': 300,
                 'tdamp': TDAMP, **kwargs}
    with pytest.raises(error, match=match):
        ReversibleNose(atoms, **arguments)
    assert_same_state(atoms, before)
    assert 'reversible' not in atoms.info


def test_atoms_moving_as_a_whole_are_warned_about():
    atoms = argon_cluster(2, 60)  # thermal momenta, total not zero
    atoms.calc = CALCULATORS['ase-lj']()
    with pytest.warns(UserWarning, match='Stationary'):
        nose(atoms)
    Stationary(atoms)
    atoms.info.pop('reversible')  # a new run, not the first one resumed
    with warnings.catch_warnings():
        warnings.simplefilter('error', UserWarning)
        nose(atoms)


def test_an_unsupported_constraint_is_refused():
    from ase.constraints import FixBondLength
    atoms = ar13()
    atoms.set_constraint(FixBondLength(0, 1))
    with pytest.raises(UnsupportedConstraintError):
        nose(atoms)


# -- gradients ---------------------------------------------------------------

def test_gradients_match_complex_step_through_a_float_nose_run():
    """backpropagate against complex-step differentiation of a plain float
    run of the same splitting written here (s = 1, pi = 0 at the start),
    for the initial state and the potential's epsilon and sigma, of a loss
    on two states of the run.  Measured relative errors: 7.1e-11 to
    4.3e-10 for the state, 7.6e-10 (epsilon) and 9.5e-11 (sigma).  With
    the adjoint of the atoms alone (the terms through s and pi left out)
    they were 0.018 to 0.17; without carrying the thermostat's cotangents
    from one segment to the next (carry=False), 0.020 to 0.36."""
    from finite_differences import argon_lj_forces, complex_step_errors
    from test_adjoint import FINE, argon, random_loss

    steps, dt = 150, 5 * units.fs
    atoms = argon(2, 40, rc=30.0, ro=29.0)
    Stationary(atoms)
    dyn = ReversibleNose(atoms, dt, 120, 50 * units.fs, energy_check=0,
                         tchain=1, **FINE)
    a_nc, b_nc = random_loss(atoms)
    x0_nc, p0_nc = atoms.positions.copy(), atoms.get_momenta()
    g_th, kT, Q = dyn.system.g, dyn.system.kT, dyn.system.Q
    potential_names = ('epsilon', 'sigma')
    dyn.run(steps)
    assert dyn.thermostat_position != 1.0
    # A loss on two states, L = <a, x_T> + <b, p_T> + <c, x_T/2>: two
    # segments, the thermostat's cotangents carried from one to the next.
    c_nc = np.random.default_rng(3).normal(size=a_nc.shape)
    half = steps // 2
    g = dyn.backpropagate(half, a_nc, b_nc, parameters=('epsilon', 'sigma'))
    with pytest.raises(ValueError, match='carry='):
        dyn.backpropagate(half, g.positions + c_nc, g.momenta)
    last = g
    g = dyn.backpropagate(half, g.positions + c_nc, g.momenta,
                          parameters=('epsilon', 'sigma'), carry=g)
    for name in potential_names:
        g.parameters[name] += last.parameters[name]
    assert np.array_equal(atoms.positions, x0_nc)
    m_n1 = atoms.get_masses()[:, None]
    potential, forces = argon_lj_forces()

    def flow_a(x_nc, p_nc, s, pi):
        return (x_nc + dt * p_nc / (m_n1 * s**2),
                pi + dt * (np.sum(p_nc**2 / m_n1) / s**3 - g_th * kT / s))

    def run(x_nc, p_nc):
        s, pi = 1.0, 0.0
        for k in range(steps):
            if k == half:
                x_half_nc = x_nc
            p_nc = p_nc + 0.5 * dt * forces(x_nc)
            s = s + 0.5 * dt * pi / Q
            x_nc, pi = flow_a(x_nc, p_nc, s, pi)
            s = s + 0.5 * dt * pi / Q
            p_nc = p_nc + 0.5 * dt * forces(x_nc)
        return x_nc, p_nc / s, x_half_nc

    def loss_imag(x_nc, p_nc):
        x_nc, p_nc, x_half_nc = run(x_nc, p_nc)
        return (np.vdot(a_nc, x_nc.imag) + np.vdot(b_nc, p_nc.imag)
                + np.vdot(c_nc, x_half_nc.imag))

    errors = complex_step_errors(loss_imag, x0_nc, p0_nc, g, potential)
    assert max(errors) < 1e-7, errors


@SLOW
def test_higher_orders_run_back_exactly_and_conserve_better():
    """Composed steps (order 4, 6) are exact too, and at the same time
    step conserve the extended energy better.  Measured on Ar13 over 1 ps
    at 5 fs, the largest change of the extended energy: 4.9e-5 eV at
    order 2, 4.7e-7 at order 4, 1.3e-7 at order 6 (at 2.5 fs: 1.2e-5,
    6.7e-8, below which rounding to the quanta is felt)."""
    drift = {}
    for order, dt_fs in ((2, 5), (4, 5), (6, 5)):
        atoms = ar13()
        dyn = nose(atoms, dt_fs, temperature_K=40, order=order)
        assert dyn.composition.order == order
        assert dyn.todict()['order'] == order
        start, e0 = dyn.counts, dyn.get_conserved_energy()
        changes = []
        dyn.attach(lambda: changes.append(
            abs(dyn.get_conserved_energy() - e0)), interval=10)
        steps = int(1000 / dt_fs)
        dyn.run(steps)
        dyn.observers.clear()
        dyn.reverse().run(steps)
        assert_same_counts(dyn.counts, start)
        drift[order] = max(changes)
    assert drift[4] < 0.05 * drift[2]
    assert drift[6] < drift[4]


# -- the chain ---------------------------------------------------------------

#: The first 16 hex digits of the sha256 of every exact variable's counts
#: (sorted by name, little-endian int64) after 200 steps of Ar13 (the
#: package's Lennard-Jones, 5 fs, 30 K, tdamp 50 fs), by order: measured
#: with ReversibleNose as it was before the chain (one thermostat), and
#: equal then for tchain=1.  A frame written by that integrator must go on
#: as it would have, so tchain=1 must stay that integrator bit for bit.
#: That integrator left a centre at rest out of ``N_f`` (3N - 3); a record
#: without ``'degrees_of_freedom'`` is resumed so (:func:`legacy_start`).
SINGLE_THERMOSTAT_DIGESTS = {2: 'df30aac3779a8545', 4: 'caa8c78e28211e66'}


def legacy_start(atoms, *args, **kwargs):
    """ReversibleNose resuming, at step 0, a restart record without
    ``'degrees_of_freedom'``, as written when a centre at rest was left
    out of ``N_f``."""
    ReversibleNose(atoms, *args, **kwargs).run(0)
    del atoms.info['reversible']['nose']['degrees_of_freedom']
    return ReversibleNose(atoms, *args, **kwargs)


def counts_digest(counts):
    import hashlib
    digest = hashlib.sha256()
    for name in sorted(counts):
        digest.update(name.encode())
        digest.update(np.ascontiguousarray(counts[name], '<i8').tobytes())
    return digest.hexdigest()[:16]


def chain_names(tchain):
    names = ['thermostat_position', 'thermostat_momentum']
    for j in range(2, tchain + 1):
        names += [f'thermostat_position_{j}', f'thermostat_momentum_{j}']
    return names


@pytest.mark.parametrize('order', [2, 4])
def test_a_chain_of_one_is_the_single_thermostat_bit_for_bit(order):
    from test_adjoint import argon
    atoms = argon(2, 40)
    Stationary(atoms)
    dyn = legacy_start(atoms, 5 * units.fs, 30, 50 * units.fs, tchain=1,
                       order=order)
    assert dyn.degrees_of_freedom == 3 * len(atoms) - 3
    dyn.run(200)
    assert sorted(dyn.counts) == sorted(
        ['position', 'momentum', 'time'] + chain_names(1))
    assert counts_digest(dyn.counts) == SINGLE_THERMOSTAT_DIGESTS[order]


@pytest.mark.parametrize('case, tchain, scheme', [
    ('Ar13 ase-lj', 2, 'velocity'),
    ('Ar13 ase-lj', 3, 'position'),
    ('Cu108 asap-emt', 3, 'velocity'),
    ('Cu108 asap-emt', 2, 'position'),
    ('Cu108 asap-emt', 1, 'position'),
])
def test_a_chain_runs_back_exactly(case, tchain, scheme):
    build, calc, dt_fs, _ = THERMOSTAT_CASES[case]
    atoms = build()
    Stationary(atoms)
    atoms.calc = CALCULATORS[calc]()
    # ASE's NoseHooverChainNVT call, tloop=1 included, plus the scheme.
    dyn = ReversibleNose(atoms, dt_fs * units.fs,
                         temperature_K=0.6 * atoms.get_temperature(),
                         tdamp=40 * dt_fs * units.fs, tchain=tchain, tloop=1,
                         scheme=scheme)
    assert (dyn.tchain, dyn.scheme) == (tchain, scheme)
    assert dyn.todict()['tchain'] == tchain
    start, shown = dyn.counts, snapshot(atoms)
    assert sorted(start) == sorted(['position', 'momentum', 'time']
                                   + chain_names(tchain))
    dyn.run(150)
    for name in start:
        assert not np.array_equal(dyn.counts[name], start[name]), name
    dyn.reverse()
    dyn.run(150)
    assert_same_counts(dyn.counts, start)
    assert_same_state(atoms, shown)
    assert dyn.get_time() == 0.0


def test_a_chain_conserves_its_extended_energy_while_the_atoms_heat_up():
    atoms = argon_cluster(2, 10)
    Stationary(atoms)
    atoms.calc = CALCULATORS['ase-lj']()
    dyn = nose(atoms, temperature_K=60, tchain=3)
    e0, k0 = dyn.get_conserved_energy(), atoms.get_kinetic_energy()
    dyn.run(300)
    heated = atoms.get_kinetic_energy() - k0
    drift = dyn.get_conserved_energy() - e0
    assert heated > 0.01
    assert abs(drift) < 1e-2 * heated
    assert all(s != 1.0 for s in dyn.thermostat_positions)


@pytest.mark.parametrize('chain', [{}, {'tchain': 3, 'scheme': 'position'}],
                         ids=['single', 'chain'])
def test_a_frame_resumes_bit_for_bit_and_runs_back_through(chain, tmp_path):
    traj = tmp_path / 'md.traj'
    tchain, scheme = chain.get('tchain', 1), chain.get('scheme', 'velocity')
    atoms = ar13()
    dyn = nose(atoms, temperature_K=200, trajectory=str(traj), **chain)
    start = dyn.counts
    dyn.run(60)
    dyn.run(40)
    straight, time = dyn.counts, dyn.get_time()
    dyn.close()

    frame = read(str(traj), 60)
    frame.calc = CALCULATORS['ase-lj']()
    assert frame.info['reversible']['nose']['tchain'] == tchain
    with warnings.catch_warnings():
        warnings.simplefilter('error', AnchorMovedWarning)
        resumed = nose(frame, temperature_K=200)  # the chain of the record
    assert (resumed.tchain, resumed.scheme) == (tchain, scheme)
    resumed.run(40)
    assert_same_counts(resumed.counts, {**straight, 'time':
                                        resumed.counts['time']})
    assert resumed.get_time() == pytest.approx(time, rel=1e-12)
    resumed.reverse().run(100)
    for name in ['position', 'momentum'] + chain_names(tchain):
        assert np.array_equal(resumed.counts[name], start[name]), name


def test_a_record_of_one_thermostat_resumes_and_another_chain_is_refused(
        tmp_path):
    traj = tmp_path / 'md.traj'
    atoms = ar13()
    dyn = nose(atoms, trajectory=str(traj), tchain=1)
    dyn.run(30)
    dyn.run(20)
    straight = dyn.counts
    dyn.close()
    frame = read(str(traj), 30)
    # As the single thermostat wrote it: no 'tchain', no 'scheme'.
    section = frame.info['reversible']['nose']
    del section['tchain'], section['scheme']
    frame.calc = CALCULATORS['ase-lj']()
    before = snapshot(frame)
    for kwargs in ({'tchain': 3}, {'scheme': 'position'}):
        with pytest.raises(ValueError, match='tchain=1, scheme=.velocity'):
            nose(frame, **kwargs)
        assert_same_state(frame, before)
    with warnings.catch_warnings():
        warnings.simplefilter('error', AnchorMovedWarning)
        resumed = nose(frame)
    assert resumed.tchain == 1
    resumed.run(20)
    for name in ('position', 'momentum', 'thermostat_position',
                 'thermostat_momentum'):
        assert np.array_equal(resumed.counts[name], straight[name]), name


def test_gradients_match_complex_step_through_a_float_chain_run():
    """As the single thermostat's test above, through a chain of three in
    the position scheme, for the initial state.  Measured relative errors:
    6.7e-10 (positions) and 6.1e-11 (momenta); with the confinement's
    curvature left out of the links' adjoint, 1.6 and 0.25."""
    from finite_differences import complex_forces
    from test_adjoint import FINE, argon

    from ase_reversible.md.nose.thermostat import (confinement_force,
                                                   chain_masses)

    steps, dt, tchain = 80, 5 * units.fs, 3
    atoms = argon(2, 40, rc=30.0, ro=29.0)
    Stationary(atoms)
    dyn = ReversibleNose(atoms, dt, 120, 50 * units.fs, energy_check=0,
                         tchain=tchain, scheme='position', **FINE)
    rng = np.random.default_rng(5)
    a_nc, b_nc = rng.normal(size=(2, len(atoms), 3))
    x0_nc, p0_nc = atoms.positions.copy(), atoms.get_momenta()
    g_th, kT = dyn.system.g, dyn.system.kT
    Q = chain_masses(g_th, kT, dyn.tdamp, tchain)
    dyn.run(steps)
    g = dyn.backpropagate(steps, a_nc, b_nc)
    assert np.array_equal(atoms.positions, x0_nc)
    m_n1 = atoms.get_masses()[:, None]

    def link(j, s, pi, h):
        # The flow of link j (from 0) over h, in place on the lists.
        if j == tchain - 1:
            s[j] = s[j] + h * pi[j] / Q[j]
            return
        r = s[j + 1]
        s[j] = s[j] + h * pi[j] / (Q[j] * r * r)
        pi[j + 1] = pi[j + 1] + h * (pi[j] ** 2 / (Q[j] * r**3)
                                     - confinement_force(kT, r))

    def run(x_nc, p_nc):
        s, pi = [1.0] * tchain, [0.0] * tchain
        h = 0.5 * dt
        for _ in range(steps):
            # A/2 C/2 B C/2 A/2; the three parts of A commute.
            x_nc = x_nc + h * p_nc / (m_n1 * s[0]**2)
            pi[0] = pi[0] + h * (np.sum(p_nc**2 / m_n1) / s[0]**3
                                 - g_th * kT / s[0])
            for j in range(tchain):
                link(j, s, pi, h)
            p_nc = p_nc + dt * complex_forces(x_nc, AR_EPSILON, AR_SIGMA)
            for j in reversed(range(tchain)):
                link(j, s, pi, h)
            pi[0] = pi[0] + h * (np.sum(p_nc**2 / m_n1) / s[0]**3
                                 - g_th * kT / s[0])
            x_nc = x_nc + h * p_nc / (m_n1 * s[0]**2)
        return x_nc, p_nc / s[0]

    h = 1e-20
    errors = []
    for dx, dp, ours in ((1, 0, g.positions), (0, 1, g.momenta)):
        u_nc = rng.normal(size=x0_nc.shape)
        x_nc, p_nc = run(x0_nc + 1j * h * dx * u_nc,
                         p0_nc + 1j * h * dp * u_nc)
        reference = (np.vdot(a_nc, x_nc.imag) + np.vdot(b_nc, p_nc.imag)) / h
        errors.append(abs(np.vdot(ours, u_nc) - reference) / abs(reference))
    assert max(errors) < 1e-7, errors


@SLOW
def test_a_chain_of_three_samples_a_copper_crystal_canonically():
    """Cu256 with asap3 EMT, momenta drawn at 1200 K on the lattice, at
    rest as a whole, a chain of three at 600 K, 5 fs, tdamp 40 steps; 2000
    steps, then the internal kinetic energy of the half-kicked momenta
    (what the thermostat reads) every 10 steps over 20,000.

    N_f is ASE's 3N, but the centre stays at rest: with g = N_f + 1 the
    weight of the 3N - 3 internal momenta at equal virtual times is
    ``exp(-(3N - 2) H / ((3N + 1) kT))``, canonical at ``T' = T (3N + 1) /
    (3N - 2)`` = 602.35 K (docs/thermostats.md).  The test tells the two
    apart: Kolmogorov-Smirnov against the Gamma distribution at T' passes,
    against that at T fails.  Measured: at T' p > 0.01 and a width 0.90
    times the canonical one; at T p = 3e-7.  Over 60,000 steps: the mean
    within 0.09% of T''s, width 0.93, p = 0.0013 (the samples are
    correlated); one thermostat: width 1.09, p = 7e-10."""
    from scipy import stats
    from ase_reversible.app.systems import copper_bulk

    atoms = copper_bulk((4, 4, 4), 1200, rattle=0)
    Stationary(atoms)
    atoms.calc = CALCULATORS['asap-emt']()  # skips without asap3
    n = len(atoms)
    dof = 3 * n - 3
    kT = units.kB * 600
    kT_internal = kT * (3 * n + 1) / (3 * n - 2)
    m_n1 = atoms.get_masses()[:, None]
    dyn = ReversibleNose(atoms, 5 * units.fs, 600, 200 * units.fs, tchain=3)
    dyn.run(2000)
    kinetic = []

    def sample():
        p_nc = atoms.get_momenta() + (
            0.5 * dyn.dt / dyn.thermostat_position) * atoms.get_forces()
        p_c = p_nc.sum(axis=0)
        kinetic.append(0.5 * ((p_nc**2 / m_n1).sum()
                              - p_c @ p_c / m_n1.sum()))
    dyn.attach(sample, interval=10)
    dyn.run(20_000)
    kinetic = np.array(kinetic)
    width = kinetic.std() / (np.sqrt(dof / 2) * kT_internal)
    p_internal, p_target = (
        stats.kstest(kinetic, 'gamma', args=(dof / 2, 0, k)).pvalue
        for k in (kT_internal, kT))
    assert p_internal > 0.01, (p_internal, width)
    assert abs(width - 1) < 0.15, width
    assert p_target < 1e-3, p_target


def test_an_unstable_chain_stops_loudly_and_stays_reversible():
    """A chain of three with tdamp = 10 steps on Cu108 (measured: the run
    stops at step 182, the fixed-point range of pi_3 exceeded)."""
    from ase_reversible import UnstableIntegrationError
    build, calc, dt_fs, _ = THERMOSTAT_CASES['Cu108 asap-emt']
    atoms = build()
    Stationary(atoms)
    atoms.calc = CALCULATORS[calc]()
    dyn = ReversibleNose(atoms, dt_fs * units.fs,
                         0.6 * atoms.get_temperature(),
                         10 * dt_fs * units.fs, tchain=3, energy_check=0)
    start = dyn.counts
    with pytest.raises(UnstableIntegrationError, match='larger tdamp'):
        dyn.run(400)
    taken = dyn.nsteps
    assert 0 < taken < 400
    dyn.reverse()
    dyn.run(taken)
    assert_same_counts(dyn.counts, start)
