"""Bad input: a clear error, and a simulation that still runs back exactly.

A refused construction must leave the atoms and any files as they were.
An error during a run must leave the integrator at its last committed
step, from which reversal still reaches the constructor state bit for bit.
"""


import numpy as np
import pytest
from ase import Atoms
from ase.calculators.lj import LennardJones
from ase.constraints import (FixAtoms, FixBondLengths, FixCartesian, FixCom,
                             FixedLine, FixedPlane, Hookean)
from ase.md.velocitydistribution import Stationary

from ase_reversible import (AnchorMovedWarning, NonFiniteForcesError,
                            NonFiniteStateError, QuantumRangeError,
                            ReversibleNose, ReversibleVerlet,
                            UnsupportedConstraintError)
from conftest import AR_RC, AR_SIGMA, DT, argon_cluster, asap_lj, ase_lj
from exactness import (assert_atoms_show_committed_state, assert_same_state,
                       forward_and_back, run_back, run_until_refused, snapshot)

EARLIER_RUN = b'frames of an earlier run\n'


def argon(calc=ase_lj, shells=2):
    atoms = argon_cluster(shells, 80)
    atoms.calc = calc()
    return atoms


# -- refused constructions ----------------------------------------------------
#
# Each spoiler damages the atoms and returns a function that repairs them.

def unchanged(atoms):
    return lambda: None


def without_calculator(atoms):
    calc, atoms.calc = atoms.calc, None

    def repair():
        atoms.calc = calc
    return repair


def with_asap_calculator(atoms):
    atoms.calc = asap_lj()
    return lambda: None


def with_mass(value):
    def spoil(atoms):
        good = atoms.get_masses()
        bad = good.copy()
        bad[3] = value
        atoms.set_masses(bad)
        return lambda: atoms.set_masses(good)
    return spoil


def with_entry(name, value):
    def spoil(atoms):
        good = atoms.arrays[name].copy()
        atoms.arrays[name][2, 1] = value

        def repair():
            atoms.arrays[name][:] = good
        return repair
    return spoil


def with_cell_entry(value):
    def spoil(atoms):
        good = atoms.cell.copy()
        atoms.cell.array[1, 1] = value
        return lambda: atoms.set_cell(good)
    return spoil


def with_constraint(make):
    def spoil(atoms):
        atoms.set_constraint(make())
        return atoms.set_constraint
    return spoil


BAD_CONSTRUCTIONS = [
    pytest.param(unchanged, {'timestep': 0.0}, ValueError,
                 'timestep must be finite and non-zero', id='timestep-zero'),
    pytest.param(unchanged, {'timestep': -0.0}, ValueError,
                 'timestep must be finite and non-zero',
                 id='timestep-negative-zero'),
    pytest.param(unchanged, {'timestep': float('nan')}, ValueError,
                 'timestep must be finite and non-zero', id='timestep-nan'),
    pytest.param(unchanged, {'timestep': float('inf')}, ValueError,
                 'timestep must be finite and non-zero', id='timestep-inf'),
    pytest.param(unchanged, {'timestep': 'five fs'}, TypeError,
                 'timestep must be a number', id='timestep-text'),
    pytest.param(unchanged, {'timestep': '5.0'}, TypeError,
                 'timestep must be a number', id='timestep-numeric-text'),
    pytest.param(unchanged, {'timestep': None}, TypeError,
                 'timestep must be a number', id='timestep-none'),
    pytest.param(without_calculator, {}, RuntimeError,
                 'The atoms have no calculator', id='no-calculator'),
    pytest.param(with_mass(0.0), {}, ValueError,
                 'Atom 3 has mass .*every mass must be positive',
                 id='mass-zero'),
    pytest.param(with_mass(-39.9), {}, ValueError,
                 'Atom 3 has mass .*every mass must be positive',
                 id='mass-negative'),
    pytest.param(with_mass(np.nan), {}, ValueError,
                 'Atom 3 has mass .*every mass must be positive',
                 id='mass-nan'),
    pytest.param(with_entry('positions', np.nan), {}, ValueError,
                 'non-finite positions', id='positions-nan'),
    pytest.param(with_entry('positions', np.inf), {}, ValueError,
                 'non-finite positions', id='positions-inf'),
    pytest.param(with_entry('momenta', np.nan), {}, ValueError,
                 'non-finite momenta', id='momenta-nan'),
    pytest.param(with_entry('momenta', -np.inf), {}, ValueError,
                 'non-finite momenta', id='momenta-inf'),
    pytest.param(with_constraint(
        lambda: [FixCom(), FixedPlane([1, 2], (1.0, 2.0, 3.0))]), {},
        UnsupportedConstraintError,
        '^FixedPlane together with FixCom is not supported.*FixCartesian',
        id='FixCom-with-FixedPlane'),
    pytest.param(with_cell_entry(np.nan), {}, ValueError,
                 'The cell has non-finite entries', id='cell-nan'),
    # Rigid molecules are supported (tests/test_rigid.py): a chain of
    # bonds, which leaves an angle free, is not a rigid body.
    pytest.param(with_constraint(lambda: FixBondLengths([[0, 1], [1, 2]])),
                 {}, UnsupportedConstraintError,
                 r'^FixBondLengths joins atoms \[0, 1, 2\] by 2 bonds: not a '
                 'rigid body', id='FixBondLengths-chain'),
    # Hookean is supported (tests/test_hookean.py), and so are rigid
    # molecules: not together.
    pytest.param(with_constraint(lambda: [FixAtoms([0]), FixCom(),
                                          Hookean(0, 1, k=5.0, rt=4.0),
                                          FixBondLengths([[2, 3]])]), {},
                 UnsupportedConstraintError,
                 '^FixAtoms, FixCom, Hookean together with rigid molecules '
                 'is not supported',
                 id='FixBondLengths-after-supported'),
    pytest.param(unchanged, {'position_quantum': 3e-12}, ValueError,
                 'position_quantum must be a positive power of two',
                 id='position-quantum-not-power-of-two'),
    pytest.param(unchanged, {'momentum_quantum': 3e-12}, ValueError,
                 'momentum_quantum must be a positive power of two',
                 id='momentum-quantum-not-power-of-two'),
    pytest.param(unchanged, {'position_quantum': -2.0**-40}, ValueError,
                 'position_quantum must be a positive power of two',
                 id='position-quantum-negative'),
    pytest.param(unchanged, {'momentum_quantum': 0.0}, ValueError,
                 'momentum_quantum must be a positive power of two',
                 id='momentum-quantum-zero'),
    pytest.param(unchanged, {'position_quantum': 2.0**-52}, QuantumRangeError,
                 'position of atom .* is outside the fixed-point range',
                 id='position-quantum-too-fine'),
    pytest.param(unchanged, {'momentum_quantum': 2.0**-60}, QuantumRangeError,
                 'momentum of atom .* is outside the fixed-point range',
                 id='momentum-quantum-too-fine'),
    pytest.param(unchanged, {'scheme': 'leapfrog'}, ValueError,
                 'scheme must be one of', id='scheme-leapfrog'),
    pytest.param(unchanged, {'force_purity': 'magic'}, ValueError,
                 'force_purity must be one of', id='force-purity-magic'),
    pytest.param(unchanged, {'force_purity': 'sorted', 'force_noise': 1e-12},
                 ValueError, "force_noise only applies to force_purity='gu",
                 id='force-noise-without-guard'),
    pytest.param(with_asap_calculator, {'force_noise': -1e-12}, ValueError,
                 'force_noise must be positive and finite',
                 id='force-noise-negative'),
    pytest.param(with_asap_calculator, {'force_purity': 'sorted'}, ValueError,
                 "force_purity='sorted' needs an ASE calculator",
                 id='sorted-without-ase-neighbour-list'),
]


@pytest.mark.parametrize('spoil, kwargs, error, match', BAD_CONSTRUCTIONS)
def test_refused_construction_leaves_atoms_and_files_alone(
        tmp_path, spoil, kwargs, error, match):
    atoms = argon()
    repair = spoil(atoms)
    positions = atoms.arrays['positions'].copy()
    momenta = atoms.arrays['momenta'].copy()
    trajectory, log = tmp_path / 'md.traj', tmp_path / 'md.log'
    trajectory.write_bytes(EARLIER_RUN)

    arguments = {'timestep': DT, **kwargs}
    timestep = arguments.pop('timestep')
    with pytest.raises(error, match=match):
        ReversibleVerlet(atoms, timestep, str(trajectory), str(log),
                         **arguments)

    # The earlier run's trajectory must survive a refused restart, and no
    # log may be started for a run that never existed.
    assert trajectory.read_bytes() == EARLIER_RUN
    assert not log.exists()
    assert np.array_equal(atoms.arrays['positions'], positions, equal_nan=True)
    assert np.array_equal(atoms.arrays['momenta'], momenta, equal_nan=True)
    assert 'reversible' not in atoms.info

    # Nothing left behind (say, in the calculator) spoils a corrected start.
    repair()
    dyn = ReversibleVerlet(atoms, DT, str(trajectory), str(log))
    start, moved = forward_and_back(dyn, 10)
    dyn.close()
    assert moved
    assert_same_state(atoms, start)


@pytest.mark.parametrize('quanta', [{'position_quantum': 2.0**-52},
                                    {'momentum_quantum': 2.0**-60}],
                         ids=['position', 'momentum'])
def test_quantum_too_fine_for_the_system_is_refused(quanta):
    what = 'position' if 'position_quantum' in quanta else 'momentum'
    with pytest.raises(QuantumRangeError,
                       match=f'^{what} of atom .* is outside the fixed-'):
        ReversibleVerlet(argon(), DT, **quanta)


@pytest.mark.parametrize('constraint, fixed_nc', [
    (lambda: FixAtoms([0, 5]), [(0, 0), (0, 1), (0, 2), (5, 0), (5, 1),
                                (5, 2)]),
    (lambda: FixCartesian([1, 2], mask=(True, False, True)),
     [(1, 0), (1, 2), (2, 0), (2, 2)]),
    (lambda: FixedPlane([3], (0, 0, 1)), []),
    (lambda: FixedLine([4], (1, 1, 0)), []),
], ids=['FixAtoms', 'FixCartesian', 'FixedPlane', 'FixedLine'])
def test_supported_constraints_run_back_exactly(constraint, fixed_nc):
    atoms = argon()
    atoms.set_constraint(constraint())
    dyn = ReversibleVerlet(atoms, DT)
    start = snapshot(atoms)
    dyn.run(20)
    # Components fixed outright do not move by even one quantum.
    for atom, axis in fixed_nc:
        assert atoms.positions[atom, axis] == start[0][atom, axis]
        assert atoms.get_momenta()[atom, axis] == 0.0
    assert not np.array_equal(atoms.positions, start[0])
    run_back(dyn, 20, start)


# -- errors during a run ------------------------------------------------------

@pytest.mark.parametrize('scheme', ['velocity', 'position'])
def test_atom_leaving_the_position_range_stops_at_a_reversible_state(scheme):
    atoms = argon()
    runaway = int(np.argmax(atoms.positions[:, 0]))
    momenta = atoms.get_momenta()
    momenta[runaway] = [80.0, 0.0, 0.0]  # about 1 Å per step, outwards
    atoms.set_momenta(momenta)
    # 2**53 quanta of 2**-48 Å: positions must stay below 32 Å.
    dyn = ReversibleVerlet(atoms, DT, scheme=scheme,
                           position_quantum=2.0**-48)
    start, steps = run_until_refused(
        dyn, 200, QuantumRangeError,
        f'^position of atom {runaway} is outside the fixed-point range')
    assert 0 < steps < 200
    assert np.abs(atoms.positions).max() < 32.0
    assert dyn.get_time() == steps * DT

    run_back(dyn, steps, start)
    assert dyn.get_time() == 0.0


def argon_pair(gap, momenta=((0, 0, 0), (0, 0, 0))):
    atoms = Atoms('Ar2', positions=[(0, 0, 0), (gap, 0, 0)], momenta=momenta)
    atoms.center(vacuum=10.0)
    atoms.calc = ase_lj()
    return atoms


@pytest.mark.parametrize('gap, scheme, overflow', [
    (2.0, 'velocity', 'momentum increment'),  # the first kick is too big
    (2.0, 'position', 'momentum increment'),
    (2.46, 'velocity', 'momentum'),  # the pair speeds apart past the range
])
def test_momentum_overflow_stops_at_a_reversible_state(gap, scheme, overflow):
    # 2**53 quanta of 2**-50: momenta must stay below 8 amu Å / time unit,
    # while the repulsion at these gaps drives them beyond.
    atoms = argon_pair(gap)
    # The range is under test: the energy check (the 5 fs step does not
    # resolve this contact) would stop the run first.
    dyn = ReversibleVerlet(atoms, DT, scheme=scheme,
                           momentum_quantum=2.0**-50, energy_check=0)
    start, steps = run_until_refused(
        dyn, 40, QuantumRangeError,
        f'^{overflow} of atom [01] is outside the fixed-point range')
    if gap > 2.0:
        assert steps > 0
    assert np.abs(atoms.get_momenta()).max() < 8.0

    run_back(dyn, steps, start)


def test_overlapping_atoms_raise_non_finite_forces_before_any_change():
    atoms = argon()
    atoms.append(atoms[5])  # a second atom exactly on top of atom 5
    dyn = ReversibleVerlet(atoms, DT)
    with np.errstate(divide='ignore', invalid='ignore'):
        before, steps = run_until_refused(
            dyn, 5, NonFiniteForcesError,
            'LennardJones returned non-finite forces')
    assert steps == 0
    assert_same_state(atoms, before)


@pytest.mark.parametrize('scheme', ['velocity', 'position'])
def test_collision_mid_step_is_rolled_back(scheme):
    # epsilon=0 makes the pair non-interacting, so it coasts until the
    # atoms sit exactly on top of each other, where even a zero epsilon
    # gives NaN forces (0 * inf).  The collision falls inside a step
    # (after the drift of kick-drift-kick, after the first half drift of
    # drift-kick-drift), so positions already moved must be put back.
    qx, qp = 2.0**-40, 2.0**-44

    def pair(gap):
        atoms = Atoms('Ar2', positions=[(10, 10, 10), (10 + gap, 10, 10)],
                      momenta=[(0, 0, 0), (-2.0, 0, 0)], cell=[30, 30, 30])
        atoms.calc = LennardJones(sigma=AR_SIGMA, epsilon=0.0, rc=AR_RC)
        return ReversibleVerlet(atoms, DT, scheme=scheme, position_quantum=qx,
                                momentum_quantum=qp)

    probe = pair(4.0)
    x0 = probe.state.ix_nc[1, 0]
    probe.run(1)
    stride = int(x0 - probe.state.ix_nc[1, 0])  # quanta per step
    assert stride > 0
    if scheme == 'position':
        assert stride % 2 == 0  # two equal half drifts
    quanta_apart = {'velocity': 5 * stride,
                    'position': 4 * stride + stride // 2}[scheme]

    dyn = pair(quanta_apart * qx)
    atoms = dyn.atoms
    assert dyn.state.ix_nc[1, 0] - dyn.state.ix_nc[0, 0] == quanta_apart
    with np.errstate(divide='ignore', invalid='ignore'):
        start, steps = run_until_refused(dyn, 10, NonFiniteForcesError,
                                         'the step was not taken')
    assert steps == 4
    assert atoms.positions[1, 0] - atoms.positions[0, 0] > 0

    run_back(dyn, 4, start)


@pytest.mark.parametrize('make_calc', [ase_lj, asap_lj],
                         ids=['ase-lj', 'asap-lj'])
@pytest.mark.parametrize('reattach', ['same', 'fresh'])
def test_calculator_removed_between_runs(make_calc, reattach):
    atoms = argon(make_calc)
    dyn = ReversibleVerlet(atoms, DT)
    start = snapshot(atoms)
    dyn.run(10)
    after_run = snapshot(atoms)
    calc = atoms.calc

    atoms.calc = None
    with pytest.raises(RuntimeError, match='lost their calculator'):
        dyn.run(5)
    assert dyn.nsteps == 10
    assert_same_state(atoms, after_run)

    atoms.calc = calc if reattach == 'same' else make_calc()
    if reattach == 'fresh' and make_calc is asap_lj:
        # asap3 calculators have no ASE parameters to compare, so a new one
        # is a new dynamics for all the integrator can tell: the anchor
        # moves, loudly.  Its forces are the same function, so the way back
        # still reaches the start.
        dyn.reverse()
        with pytest.warns(AnchorMovedWarning, match='the calculator'):
            dyn.run(10)
        assert_same_state(atoms, start)
        return
    run_back(dyn, 10, start)


@pytest.mark.parametrize('change', ['removed', 'added'])
def test_changed_number_of_atoms_is_refused(change):
    atoms = argon()
    dyn = ReversibleVerlet(atoms, DT)
    start = snapshot(atoms)
    dyn.run(10)
    after_run = snapshot(atoms)

    if change == 'removed':
        last = atoms[-1:]
        del atoms[-1]
    else:
        atoms.append(atoms[0])
        atoms.positions[-1] += 4.0
    with pytest.raises(ValueError, match='number of atoms changed'):
        dyn.run(5)
    assert dyn.nsteps == 10

    if change == 'removed':
        atoms.extend(last)
    else:
        del atoms[-1]
    assert_same_state(atoms, after_run)
    run_back(dyn, 10, start)


@pytest.mark.parametrize('edit', ['positions', 'momenta'])
def test_edit_between_runs_becomes_the_new_reversal_anchor(edit):
    atoms = argon(asap_lj, shells=3)
    dyn = ReversibleVerlet(atoms, DT)
    qx, qp = dyn.grid.position_quantum, dyn.grid.momentum_quantum
    dyn.run(10)
    before_edit = snapshot(atoms)

    if edit == 'positions':
        atoms.positions += 0.01
    else:
        atoms.set_momenta(1.01 * atoms.get_momenta())
    # What the integrator must take: the edit snapped to the grid.
    edited = (np.rint(atoms.get_positions() / qx) * qx,
              np.rint(atoms.get_momenta() / qp) * qp)
    changed = 0 if edit == 'positions' else 1
    assert not np.array_equal(edited[changed], before_edit[changed])
    assert np.array_equal(edited[1 - changed], before_edit[1 - changed])

    with pytest.warns(AnchorMovedWarning,
                      match='changed outside ReversibleVerlet'):
        dyn.run(10)
    assert dyn.get_time() == 20 * DT

    # Back to the edit, not past it to the constructor state.
    run_back(dyn, 10, edited)
    assert dyn.get_time() == 10 * DT


# -- values the grid cannot hold, set between runs ---------------------------
#
# The values they overwrote are gone: the integrator puts its last exact
# state back on the atoms, says so, and reversal still reaches the anchor.

UNHOLDABLE = [
    ('positions', np.nan, NonFiniteStateError, 'position of atom 2 is NaN'),
    ('positions', -np.inf, NonFiniteStateError,
     'position of atom 2 is infinite'),
    ('momenta', np.nan, NonFiniteStateError, 'momentum of atom 2 is NaN'),
    ('momenta', np.inf, NonFiniteStateError, 'momentum of atom 2 is infinite'),
    ('positions', 1e9, QuantumRangeError,
     'position of atom 2 is outside the fixed-point range'),
    ('momenta', -1e9, QuantumRangeError,
     'momentum of atom 2 is outside the fixed-point range'),
]


def spoil_between_steps(atoms, name, value):
    atoms.arrays[name][2, 1] = value
    atoms.arrays[name][5, 0] = value


@pytest.mark.parametrize('name, value, error, match', UNHOLDABLE,
                         ids=[f'{n}-{v}' for n, v, _, _ in UNHOLDABLE])
@pytest.mark.parametrize('loop', ['run', 'irun'])
def test_unholdable_edit_between_runs_puts_the_last_exact_state_back(
        loop, name, value, error, match):
    atoms = argon()
    dyn = ReversibleVerlet(atoms, DT)
    start = snapshot(atoms)
    if loop == 'run':
        dyn.run(10)
        spoil_between_steps(atoms, name, value)
        last_exact = dyn.state
        with pytest.raises(error, match=match) as refused:
            dyn.run(5)
    else:
        with pytest.raises(error, match=match) as refused:
            for _ in dyn.irun(15):
                if dyn.nsteps == 10:
                    last_exact = dyn.state
                    spoil_between_steps(atoms, name, value)
    # The message says what was done and that the way back works.
    assert 'put back to the last exact state' in str(refused.value)
    if error is NonFiniteStateError:
        assert '1 more atom with' in str(refused.value)
    assert dyn.nsteps == 10 and dyn.get_time() == 10 * DT
    assert np.array_equal(dyn.state.ix_nc, last_exact.ix_nc)
    assert np.array_equal(dyn.state.ip_nc, last_exact.ip_nc)
    assert_atoms_show_committed_state(dyn)
    run_back(dyn, 10, start)


@pytest.mark.parametrize('name', ['positions', 'momenta'])
def test_nan_set_on_a_nose_run_is_refused_and_runs_back(name):
    atoms = argon()
    Stationary(atoms)
    dyn = ReversibleNose(atoms, DT, temperature_K=80, tdamp=100 * DT)
    start = dyn.counts
    dyn.run(6)
    shown = snapshot(atoms)
    spoil_between_steps(atoms, name, np.nan)
    with pytest.raises(NonFiniteStateError, match='put back'):
        dyn.run(4)
    assert_same_state(atoms, shown)
    dyn.reverse()
    dyn.run(6)
    for key, counts in dyn.counts.items():
        assert np.array_equal(counts, start[key]), key


@pytest.mark.parametrize('kwargs, message', [
    ({'energy_check': -1}, 'energy_check must be a whole number'),
    ({'energy_check': 2.5}, 'energy_check must be a whole number'),
    ({'energy_check': True}, 'energy_check must be a whole number'),
    ({'energy_tolerance': 0.0}, 'energy_tolerance must be positive'),
    ({'energy_tolerance': float('nan')}, 'energy_tolerance must be positive'),
])
def test_bad_energy_check_settings_are_refused(kwargs, message):
    atoms = argon_cluster(2, 80)
    atoms.calc = asap_lj()
    with pytest.raises(ValueError, match=message):
        ReversibleVerlet(atoms, DT, **kwargs)


def test_a_cell_filter_is_refused_with_advice():
    from ase.calculators.emt import EMT
    from ase.filters import FrechetCellFilter
    from conftest import copper_bulk
    atoms = copper_bulk((2, 2, 2), 300)
    atoms.calc = EMT()
    start = snapshot(atoms)
    with pytest.raises(TypeError, match='pass the Atoms themselves'):
        ReversibleVerlet(FrechetCellFilter(atoms), DT)
    assert_same_state(atoms, start)
