"""Rigid molecules as exact variables: TIP3P water (FixBondLengths
triangles) and linear acetonitrile (FixLinearTriatomic) run out and back
bit for bit under ReversibleVerlet, hold their shapes, follow the
dynamics ASE's RATTLE integrates, restart exactly from a frame, and what
is not supported yet is refused before anything changes."""

import textwrap
import warnings

import numpy as np
import pytest
from ase import Atoms, units
from ase.calculators.acn import ACN, m_me, r_cn, r_mec
from ase.calculators.emt import EMT
from ase.calculators.tip3p import TIP3P, angleHOH, rOH
from ase.constraints import FixAtoms, FixBondLengths, FixLinearTriatomic
from ase.io import read
from ase.md.verlet import VelocityVerlet

from ase_reversible import (AnchorMovedWarning, ReversibleBussi,
                            ReversibleLangevin, ReversibleNose,
                            ReversibleVerlet, UnstableIntegrationError,
                            UnsupportedConstraintError)
from ase_reversible.app.systems import water_box
from ase_reversible.core import rigid
from machines import emulation_works, run_leg
from tiers import SLOW

VARIABLES = ('position', 'momentum', 'orientation', 'angular_momentum')


def acetonitrile_dimer():
    """ASE's test_rattle_linear dimer: two rigid linear molecules."""
    dimer = Atoms('CCNCCN', [(-r_mec, 0, 0), (0, 0, 0), (r_cn, 0, 0),
                             (r_mec, 3.7, 0), (0, 3.7, 0), (-r_cn, 3.7, 0)])
    masses = dimer.get_masses()
    masses[::3] = m_me
    dimer.set_masses(masses)
    dimer.set_constraint(FixLinearTriatomic(triples=[(0, 1, 2), (3, 4, 5)]))
    dimer.calc = ACN()
    return dimer


def assert_same_counts(a, b):
    for name in VARIABLES:
        assert np.array_equal(a[name], b[name]), name


def round_trip(atoms, dt, steps, **kwargs):
    dyn = ReversibleVerlet(atoms, dt * units.fs, **kwargs)
    start = dyn.counts
    x0, p0 = atoms.get_positions(), atoms.get_momenta()
    dyn.run(steps)
    moved = dyn.counts
    assert not np.array_equal(moved['orientation'], start['orientation'])
    assert not np.array_equal(moved['angular_momentum'],
                              start['angular_momentum'])
    dyn.reverse().run(steps)
    assert_same_counts(dyn.counts, start)
    assert np.array_equal(atoms.positions, x0)
    assert np.array_equal(atoms.get_momenta(), p0)
    return dyn


@pytest.mark.parametrize('dt', [1.0, 2.0])
def test_water_runs_back_bit_for_bit(dt):
    round_trip(water_box(3), dt, 60)


@pytest.mark.parametrize('dt', [1.0, 2.0])
@SLOW
def test_64_waters_run_back_bit_for_bit(dt):
    # 10,000 steps each way: benchmarks/rigid.py (docs/benchmarks.md).
    round_trip(water_box(4, seed=1), dt, 300)


def test_linear_molecules_run_back_bit_for_bit():
    dyn = round_trip(acetonitrile_dimer(), 2.0, 100)
    # No spin about the line: the angular momentum along it stays 0.
    assert not dyn.counts['angular_momentum'][:, 0].any()


def test_shapes_hold_to_the_last_bits():
    box = water_box(3)
    ReversibleVerlet(box, 2 * units.fs).run(100)
    for i in range(27):
        oh = box.get_distances(3 * i, [3 * i + 1, 3 * i + 2], mic=True)
        hh = box.get_distance(3 * i + 1, 3 * i + 2, mic=True)
        assert np.abs(oh - rOH).max() < 1e-13
        assert abs(hh - 2 * rOH * np.sin(np.radians(angleHOH) / 2)) < 1e-13


def ase_and_exact(make, dt, steps):
    """The potential energy's change over ``steps`` steps of ``dt`` fs
    under ASE's VelocityVerlet (RATTLE) and ReversibleVerlet."""
    changes = []
    for cls in (VelocityVerlet, ReversibleVerlet):
        atoms = make()
        e0 = atoms.get_potential_energy()
        cls(atoms, dt * units.fs).run(steps)
        changes.append(atoms.get_potential_energy() - e0)
    return changes


def test_linear_dynamics_is_rattles():
    # The same equations of motion: at 2 fs the two integrators agree to
    # 4e-9 eV over 200 fs of ASE's acetonitrile dimer (they differ from
    # the converged value by 5e-7 eV), where ASE's md forces (redistributed
    # for RATTLE: the molecules' total forces 29% off) gave 8e-4 eV.
    ase, exact = ase_and_exact(acetonitrile_dimer, 2.0, 100)
    assert abs(ase - exact) < 1e-7


def water_dimer():
    """ASE's test_rattle water dimer (S22)."""
    from ase.data.s22 import create_s22_system
    dimer = create_s22_system('Water_dimer')
    for m in (0, 3):
        dimer.set_angle(m + 1, m, m + 2, angleHOH)
        dimer.set_distance(m, m + 1, rOH, fix=0)
        dimer.set_distance(m, m + 2, rOH, fix=0)
    dimer.set_constraint(FixBondLengths(
        [(3 * i + a, 3 * i + b) for i in range(2)
         for a, b in ((0, 1), (0, 2), (1, 2))]))
    dimer.calc = TIP3P()
    return dimer


@SLOW
def test_water_dynamics_is_rattles():
    # At 0.5 fs both are within 1e-6 eV of the converged change (-0.02748
    # eV over 200 fs); a wrong torque or frame moves it by 1e-3 or more.
    ase, exact = ase_and_exact(water_dimer, 0.5, 400)
    assert abs(ase - exact) < 2e-6


def test_a_frame_restarts_exactly(tmp_path):
    box = water_box(3)
    path = tmp_path / 'water.traj'
    with ReversibleVerlet(box, 1 * units.fs, trajectory=str(path)) as dyn:
        start = dyn.counts
        dyn.run(20)
        at_frame = dyn.counts
        dyn.run(10)
        end = dyn.counts
    frame = read(path, index=20)
    frame.calc = TIP3P(rc=box.calc.rc)
    frame.set_constraint(box.constraints)
    with warnings.catch_warnings():
        warnings.simplefilter('error')
        resumed = ReversibleVerlet(frame, 1 * units.fs)
    assert_same_counts(resumed.counts, at_frame)
    assert resumed.get_time() == 20 * units.fs
    assert resumed.forces_match_record
    resumed.run(10)
    assert_same_counts(resumed.counts, end)
    resumed.reverse().run(30)
    assert_same_counts(resumed.counts, start)


def written_frame(folder):
    """The last frame of a short ReversibleVerlet run of 27 waters, read
    back with ``ase.io.read``, and the box that wrote it."""
    box = water_box(3)
    path = folder / 'water.traj'
    with ReversibleVerlet(box, 1 * units.fs, trajectory=str(path)) as dyn:
        dyn.run(2)
    return read(path, index=-1), box


def test_a_frame_whose_constraint_holds_other_lengths_starts_anew(tmp_path):
    frame, box = written_frame(tmp_path)
    lengths = frame.constraints[0].initialize_bond_lengths(frame)
    lengths[0] += 0.01
    frame.set_constraint(FixBondLengths(frame.constraints[0].pairs,
                                        bondlengths=lengths))
    frame.calc = TIP3P(rc=box.calc.rc)
    dyn = ReversibleVerlet(frame, 1 * units.fs)
    assert dyn.get_time() == 0.0  # the record's shapes are not taken
    assert abs(frame.get_distance(0, 1) - lengths[0]) < 1e-12


def test_a_frame_without_its_constraint_warns_that_it_runs_free(tmp_path):
    frame, box = written_frame(tmp_path)
    del frame.constraints
    frame.calc = TIP3P(rc=box.calc.rc)
    with pytest.warns(AnchorMovedWarning, match='set the constraint again'):
        dyn = ReversibleVerlet(frame, 1 * units.fs)
    assert dyn.system.layout is None and dyn.get_time() == 0.0


def test_an_edit_between_runs_is_taken_and_snapped():
    box = water_box(3)
    dyn = ReversibleVerlet(box, 1 * units.fs)
    dyn.run(5)
    box.positions[0] += 0.01  # a stretched O-H: the body is fitted again
    with pytest.warns(UserWarning, match='changed outside ReversibleVerlet'):
        dyn.run(0)
    assert abs(box.get_distance(0, 1, mic=True) - rOH) < 1e-13
    anchor = dyn.counts
    dyn.run(10)
    dyn.reverse().run(10)
    assert_same_counts(dyn.counts, anchor)


def test_a_turn_too_large_is_refused_and_the_state_kept():
    box = water_box(3)
    dyn = ReversibleVerlet(box, 40 * units.fs, energy_check=0)
    before = dyn.counts
    with pytest.raises(UnstableIntegrationError, match='would turn by'):
        dyn.run(50)
    dyn.reverse().run(dyn.nsteps)
    assert_same_counts(dyn.counts, before)


def test_the_rotation_by_shears_is_a_rotation_and_undone_bitwise():
    rng = np.random.default_rng(2)
    q = rng.normal(size=(6, 4))
    q /= np.linalg.norm(q, axis=1)[:, None]
    q_counts = np.rint(q / rigid.ORIENTATION_QUANTUM)
    l_counts = np.rint(rng.normal(size=(6, 3)) * 2.0**40)
    theta = rng.uniform(-0.5, 0.5, 6)
    a0 = rigid.rotation_matrices(q_counts)
    for k in range(3):
        q1, l1 = q_counts.copy(), l_counts.copy()
        rigid.turn_about_axis(q1, l1, k, theta)
        turn = np.zeros((6, 3, 3))
        i, j = (k + 1) % 3, (k + 2) % 3
        turn[:, k, k] = 1.0
        turn[:, i, i] = turn[:, j, j] = np.cos(theta)
        turn[:, j, i], turn[:, i, j] = np.sin(theta), -np.sin(theta)
        assert np.abs(rigid.rotation_matrices(q1) - a0 @ turn).max() < 1e-14
        # L turns the other way, to within a count of rounding per shear.
        expected = np.einsum('bji,bj->bi', turn, l_counts)
        assert np.abs(l1 - expected).max() <= 3.0
        rigid.turn_about_axis(q1, l1, k, -theta)
        assert np.array_equal(q1, q_counts) and np.array_equal(l1, l_counts)
    assert np.array_equal(rigid.tan(-theta), -rigid.tan(theta))
    assert np.abs(rigid.tan(theta) - np.tan(theta)).max() < 1e-16


def test_what_is_not_supported_is_refused_before_anything_changes():
    box = water_box(3)
    x0 = box.get_positions()
    with pytest.raises(UnsupportedConstraintError,
                       match='FixBondLengths makes molecules rigid: '
                             'ReversibleVerlet runs them'):
        ReversibleNose(box, 1 * units.fs, temperature_K=300,
                       tdamp=100 * units.fs)
    assert np.array_equal(box.positions, x0)
    box.set_constraint([FixAtoms([0]), *box.constraints])
    with pytest.raises(UnsupportedConstraintError,
                       match='FixAtoms together with rigid molecules'):
        ReversibleVerlet(box, 1 * units.fs)
    assert np.array_equal(box.positions, x0)


def test_a_change_in_mid_run_is_refused_the_state_kept():
    box = water_box(3)
    dyn = ReversibleVerlet(box, 1 * units.fs)
    start = dyn.counts
    dyn.run(5)
    cell = box.get_cell()
    box.set_cell(cell * 1.01, scale_atoms=False)
    with pytest.raises(UnsupportedConstraintError,
                       match='cell.*takes edits of positions and momenta '
                             'only'):
        dyn.run(1)
    box.set_cell(cell)  # undone: the run goes on
    dyn.reverse().run(5)
    assert_same_counts(dyn.counts, start)


def test_backpropagate_under_bussi_is_refused_the_state_kept():
    box = water_box(3)
    dyn = ReversibleBussi(box, 1 * units.fs, temperature_K=300,
                          taut=50 * units.fs, seed=1)
    dyn.run(5)
    moved = dyn.counts
    with pytest.raises(UnsupportedConstraintError,
                       match='backpropagate does not run through rigid'):
        dyn.backpropagate(5, np.ones((81, 3)))
    assert_same_counts(dyn.counts, moved)


#: Quanta fine enough that the exact run's rounding is noise far below a
#: finite difference's change.
FINE = {'position_quantum': 2.0**-46, 'momentum_quantum': 2.0**-50}


def gradient_errors(atoms, steps, scale=1.0, dynamics=ReversibleVerlet):
    """For a linear loss on the atoms' positions and momenta after
    ``steps`` steps of 1 fs: the relative difference between
    backpropagate's gradient on each exact variable, along a random
    direction, and the central difference of whole exact runs."""
    dyn = dynamics(atoms, 1 * units.fs, **FINE)
    rng = np.random.default_rng(0)
    cx, cp = rng.normal(size=(2, len(atoms), 3))

    def loss():
        return float((cx * atoms.positions).sum()
                     + (cp * atoms.get_momenta()).sum())

    start = dyn.counts
    dyn.run(steps)
    g = dyn.backpropagate(steps, cx, cp)
    assert_same_counts(dyn.counts, start)
    assert np.array_equal(g.positions, g.thermostat['position'])
    sizes = {'position': 1e-7, 'momentum': 1e-7, 'orientation': 1e-8,
             'angular_momentum': 1e-7}
    errors = {}
    for name in VARIABLES:
        quantum = dyn.system.variables[name].quantum
        step = np.rint(rng.normal(size=start[name].shape) * scale
                       * sizes[name] / quantum).astype(np.int64)
        ends = []
        for sign in (1, -1):
            dyn._install({**start, name: start[name] + sign * step})
            dyn.run(steps)
            ends.append(loss())
        dyn._install(start)
        difference = 0.5 * (ends[0] - ends[1])
        adjoint = float((g.thermostat[name] * step * quantum).sum())
        errors[name] = abs(adjoint - difference) / abs(difference)
    return errors


def test_gradients_through_rigid_bodies_match_finite_differences():
    # Measured 6e-8 to 3.3e-7 for the linear molecules over 50 steps, 2e-8
    # to 7e-8 for water over 20; a wrong rule is off by its whole size.
    errors = gradient_errors(acetonitrile_dimer(), 50, scale=10.0)
    assert max(errors.values()) < 1e-6, errors
    errors = gradient_errors(water_box(3), 20, scale=10.0)
    assert max(errors.values()) < 1e-6, errors


@SLOW
def test_gradients_through_200_steps_of_water_match_finite_differences():
    # Measured 5e-7 to 2e-6: at this step the differences' rounding noise
    # and their curvature balance (ten times it: up to 5e-3, curvature; a
    # tenth: up to 6e-5, noise).
    errors = gradient_errors(water_box(3), 200)
    assert max(errors.values()) < 1e-5, errors


@pytest.mark.parametrize('dynamics', [ReversibleVerlet, ReversibleLangevin])
def test_a_loss_on_several_states_equals_its_segments(dynamics):
    """One retrace with loss= against segments joined by carry= (the
    bodies carry the gradient between them): the same gradients but for
    the association of sums."""
    from ase_reversible.md.rigid.adjoint import shown_cotangents
    box = water_box(3)
    kwargs = ({'temperature_K': 300, 'friction': 0.02 / units.fs,
               'seed': 2} if dynamics is ReversibleLangevin else {})
    dyn = dynamics(box, 1 * units.fs, **kwargs)
    rng = np.random.default_rng(1)
    weights = {k: tuple(rng.normal(size=(2, 81, 3))) for k in (0, 10, 20)}
    dyn.run(20)
    whole = dyn.backpropagate(20, loss=lambda atoms, k: weights.get(k),
                              every=10)
    dyn.run(20)
    g = dyn.backpropagate(10, *weights[20])
    with pytest.raises(ValueError, match='carry'):
        dyn.backpropagate(10, *weights[10])
    g = dyn.backpropagate(10, *weights[10], carry=g)
    last = shown_cotangents(dyn.system, *weights[0])
    for name in VARIABLES:
        joined = g.thermostat[name] + last[name]
        scale = np.abs(joined).max()
        assert np.abs(whole.thermostat[name] - joined).max() < 1e-12 * scale


def test_guarded_forces_are_refused():
    slab = Atoms('Cu4', positions=[(0, 0, 0), (2.5, 0, 0), (0, 2.5, 0),
                                   (0, 0, 2.5)])
    slab += Atoms('COO', positions=[(5, 5, 5), (5, 5, 6.16),
                                    (5, 5, 3.84)])
    slab.set_constraint(FixLinearTriatomic(triples=[(5, 4, 6)]))
    slab.calc = EMT()
    with pytest.raises(UnsupportedConstraintError, match='guarded'):
        ReversibleVerlet(slab, 1 * units.fs, force_noise=1e-9)


def test_the_thermostats_run_rigid_water_back_bit_for_bit():
    for make in (lambda atoms: ReversibleLangevin(
            atoms, 2 * units.fs, temperature_K=300, friction=0.02 / units.fs,
            seed=1),
                 lambda atoms: ReversibleBussi(
            atoms, 2 * units.fs, temperature_K=300, taut=50 * units.fs,
            seed=1)):
        box = water_box(3)
        dyn = make(box)
        start = dyn.counts
        dyn.run(40)
        dyn.reverse().run(40)
        assert_same_counts(dyn.counts, start)


@SLOW
@pytest.mark.parametrize('name', ['langevin', 'bussi'])
def test_the_thermostats_sample_rigid_water_canonically(name):
    """27 waters at 300 K, 2 fs: each molecule's translational and
    rotational kinetic energies follow Gamma(3/2, kT) (Kolmogorov-Smirnov
    over 200 samples of each molecule, every 20 fs after 2 ps), and the
    mean temperature over the 6 N degrees of freedom is 300 K to 3%."""
    from test_bussi import gamma_ks_pvalue
    box = water_box(3, seed=4)
    if name == 'langevin':
        dyn = ReversibleLangevin(box, 2 * units.fs, temperature_K=300,
                                 friction=0.05 / units.fs, fixcm=False,
                                 seed=3)
    else:
        dyn = ReversibleBussi(box, 2 * units.fs, temperature_K=300,
                              taut=50 * units.fs, seed=3)
    dyn.run(1000)
    layout, system = dyn.system.layout, dyn.system
    translational, rotational, temperatures = [], [], []
    for _ in range(200):
        dyn.run(10)
        p = system.p.floats[len(layout.free_f):]
        translational.append((p * p).sum(axis=1) / (2 * layout.masses_b))
        spin = system.l.floats
        rotational.append(0.5 * (spin * spin
                                 * layout.inverse_moments_bc).sum(axis=1))
        temperatures.append(box.get_temperature())
    kT = units.kB * 300
    for energies in (translational, rotational):
        assert gamma_ks_pvalue(np.concatenate(energies), 1.5, kT) > 1e-3
    assert abs(np.mean(temperatures) / 300 - 1) < 0.03


# -- across machines ---------------------------------------------------------

#: Rigid Ar3 triangles or Ar2 dumbbells under the package's portable
#: LennardJones, out on one machine and back on another: the turns, the
#: rotations and the torques have the same bits everywhere.
CROSS = textwrap.dedent('''
    import warnings
    import numpy as np
    from ase import Atoms, units
    from ase.constraints import FixBondLengths
    from ase.io import read
    from ase_reversible import LennardJones, ReversibleLangevin, \\
        ReversibleVerlet
    warnings.simplefilter('ignore')

    def molecules():
        rng = np.random.default_rng(6)
        shape = ([[0, 0, 0], [3.8, 0, 0], [1.9, 3.3, 0]] if SIZE == 3
                 else [[0, 0, 0], [3.8, 0, 0]])
        atoms = Atoms()
        for index in np.ndindex(2, 2, 2):
            m = Atoms('Ar' * SIZE, shape)
            m.rotate(rng.uniform(0, 360), rng.normal(size=3))
            m.translate(7.0 * np.array(index))
            atoms += m
        bonds = [(SIZE * i + a, SIZE * i + b) for i in range(8)
                 for a in range(SIZE) for b in range(a + 1, SIZE)]
        atoms.set_constraint(FixBondLengths(bonds))
        atoms.set_momenta(rng.normal(size=(len(atoms), 3)) * 0.3)
        return atoms

    def dynamics(atoms, **kwargs):
        atoms.calc = LennardJones(sigma=3.4, epsilon=0.0104, rc=8.5)
        if DYNAMICS == 'langevin':
            return ReversibleLangevin(atoms, 5 * units.fs, temperature_K=80,
                                      friction=0.01 / units.fs, seed=2,
                                      **kwargs)
        return ReversibleVerlet(atoms, 5 * units.fs)
''')
CROSS_OUT = textwrap.dedent('''
    atoms = molecules()
    dyn = dynamics(atoms)
    np.savez('start.npz', **dyn.counts)
    dyn.run(STEPS)
    atoms.write('run.traj')
    if DYNAMICS == 'langevin':
        dyn.write_buffer('buffer.npz')
''')
CROSS_BACK = textwrap.dedent('''
    atoms = read('run.traj')
    atoms.set_constraint(molecules().constraints)
    extra = {'buffer': 'buffer.npz'} if DYNAMICS == 'langevin' else {}
    dyn = dynamics(atoms, **extra)
    dyn.reverse().run(STEPS)
    np.savez('end.npz', **dyn.counts)
''')


@pytest.fixture(scope='module')
def machines_differ(tmp_path_factory):
    if not emulation_works(tmp_path_factory.mktemp('emulation')):
        pytest.skip('the emulated machines compute the same bits here')


@pytest.mark.parametrize('size, dynamics, steps', [
    (3, 'verlet', 30),
    pytest.param(2, 'verlet', 60, marks=SLOW),
    pytest.param(3, 'langevin', 60, marks=SLOW)])
def test_out_on_one_machine_back_on_another(tmp_path, machines_differ, size,
                                            dynamics, steps):
    head = f'SIZE, DYNAMICS, STEPS = {size}, {dynamics!r}, {steps}\n'
    run_leg('native', head + CROSS + CROSS_OUT, tmp_path)
    run_leg('sse4', head + CROSS + CROSS_BACK, tmp_path)
    with np.load(tmp_path / 'start.npz') as start, \
            np.load(tmp_path / 'end.npz') as end:
        assert sorted(start.files) == sorted(VARIABLES)
        for name in VARIABLES:
            assert np.array_equal(start[name], end[name]), name
