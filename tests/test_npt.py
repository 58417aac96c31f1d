"""ReversibleIsotropicNPT and ReversibleNPT: exact out and back with a
moving cell, restarts, the piston's force against the energy, gradients,
refusals.

Every exact variable (scaled positions and momenta, the cell's scale and
its momentum) and what the atoms show (positions, momenta, cell) is
compared with ``np.array_equal``.
"""

import warnings

import numpy as np
import pytest
from ase import units
from ase.calculators.emt import EMT
from ase.io import Trajectory, read

from ase_reversible import (AnchorMovedWarning, ReversibleIsotropicNPT,
                            ReversibleNPT, UnstableIntegrationError,
                            UnsupportedConstraintError)
from ase_reversible.core.portable import rows_times_matrix
from ase_reversible.md.npt import LAMBDA_MIN, VirialKick, cell_volume
from ase_reversible.md.npt.cell import COLUMNS, ROWS, CellVirial
from conftest import (AR_EPSILON, AR_RC, AR_SIGMA, argon_bulk, asap_emt,
                      ase_lj, copper_bulk)
from tiers import SLOW, tiered

DT = 5 * units.fs


def npt(atoms, **kwargs):
    settings = dict(temperature_K=300, pressure_au=1.0 * units.GPa,
                    tdamp=50 * units.fs, pdamp=100 * units.fs, seed=7)
    settings.update(kwargs)
    dt = settings.pop('timestep', DT)
    return ReversibleIsotropicNPT(atoms, dt, **settings)


def shown(atoms):
    return (atoms.positions.copy(), atoms.get_momenta(),
            atoms.cell.array.copy())


def assert_back(dyn, state, seen, emptied=True):
    now = dyn.engine.snapshot()
    for name, counts in state.items():
        assert np.array_equal(now[name], counts), name
    for a, b in zip(shown(dyn.atoms), seen):
        assert np.array_equal(a, b)
    if emptied:  # back at the anchor: the friction's digits all returned
        assert not dyn.friction_step.active_buffers()
        assert not dyn.friction_step.piston.active_buffers()


def assert_same_counts(dyn, reference):
    """``dyn`` holds the exact variables of ``reference``, bit for bit."""
    for name, counts in reference.engine.snapshot().items():
        assert np.array_equal(dyn.engine.snapshot()[name], counts), name


def out_and_back(dyn, steps, full_cell=False):
    """Run out ``steps``, check the cell moved (its volume by 0.1% at
    least; with ``full_cell``, every entry of its deformation), run back,
    demand the start bit for bit."""
    state, seen = dyn.engine.snapshot(), shown(dyn.atoms)
    volume = dyn.atoms.get_volume()
    dyn.run(steps)
    if full_cell:
        m = dyn.barostat_position
        # Every entry of the deformation moved: the cell changed its shape.
        assert np.all(m[ROWS, COLUMNS] != np.eye(3)[ROWS, COLUMNS])
        assert np.array_equal(dyn.atoms.cell.array,
                              rows_times_matrix(dyn.reference_cell, m))
    else:
        assert abs(dyn.atoms.get_volume() / volume - 1) > 1e-3
        assert not np.array_equal(dyn.atoms.cell.array, seen[2])
        assert np.array_equal(dyn.atoms.cell.array,
                              dyn.reference_cell * dyn.barostat_position)
    dyn.reverse()
    with warnings.catch_warnings():
        warnings.simplefilter('error', AnchorMovedWarning)
        dyn.run(steps)
    assert_back(dyn, state, seen)


def copper():
    atoms = copper_bulk((2, 2, 2), 300)
    atoms.calc = EMT()
    return atoms


def argon(calc=ase_lj):
    # Liquid argon at 120 K: the solid's lattice, hot.
    atoms = argon_bulk((2, 2, 2), 120)
    atoms.calc = calc()
    return atoms


def our_lj():
    from ase_reversible import LennardJones
    return LennardJones(epsilon=AR_EPSILON, sigma=AR_SIGMA, rc=AR_RC)


def test_copper_emt_runs_out_and_back_with_the_cell():
    out_and_back(npt(copper()), 30)


# The package's LennardJones (plain numpy) takes twice ASE's time here.
@pytest.mark.parametrize('calc', tiered([ase_lj, our_lj], quick=[ase_lj]))
def test_argon_lj_runs_out_and_back_with_the_cell(calc):
    dyn = npt(argon(calc), temperature_K=120, pressure_au=0.05 * units.GPa,
              pdamp=200 * units.fs)
    out_and_back(dyn, 30)


def test_asap3_emt_runs_out_and_back_with_the_cell():
    atoms = copper_bulk((2, 2, 2), 300)
    atoms.calc = asap_emt()  # skips where asap3 is missing
    out_and_back(npt(atoms), 30)


def test_observers_see_positions_momenta_and_cell_of_the_exact_state():
    dyn = npt(copper())
    seen = []

    def look():
        s = dyn.system
        lam = s.lam_value()
        assert np.array_equal(dyn.atoms.positions, s.x.floats * lam)
        assert np.array_equal(dyn.atoms.get_momenta(), s.p.floats / lam)
        assert np.array_equal(dyn.atoms.cell.array, s.cell0 * lam)
        seen.append(dyn.atoms.get_volume())
    dyn.attach(look)
    dyn.run(5)
    assert len(set(seen)) == len(seen) == 6


def test_the_piston_force_is_minus_the_energy_derivative_in_lambda():
    """``G - 2kT/lambda + 3 P V0 lambda**2 = -dU/dlambda`` at fixed scaled
    positions, by a central difference of the energy under a uniform
    scaling of positions and cell: the stress's sign and factor."""
    atoms = copper()
    dyn = npt(atoms)
    dyn.run(3)
    s = dyn.system
    lam = s.lam_value()
    G = VirialKick(s).force(s.kick.stress_trace())
    minus_dU = G - 2 * s.kT / lam + 3 * s.pressure * s.V0 * lam**2

    probe = atoms.copy()
    probe.calc = EMT()
    d = 1e-5

    def energy(scale):
        probe.set_cell(atoms.cell.array * scale, scale_atoms=False)
        probe.positions = atoms.positions * scale
        return probe.get_potential_energy()
    derivative = (energy(1 + d / lam) - energy(1 - d / lam)) / (2 * d)
    assert minus_dU == pytest.approx(-derivative, rel=1e-5, abs=1e-6)
    assert abs(minus_dU) > 1.0  # eV: a test that could fail on the sign


def test_volume_is_computed_in_plain_arithmetic():
    cell = np.array([[3.0, 0.1, 0.0], [0.2, 4.0, 0.3], [0.0, 0.1, 5.0]])
    assert cell_volume(cell) == pytest.approx(abs(np.linalg.det(cell)),
                                              rel=1e-14)


def test_a_frame_and_its_buffer_resume_the_run_bit_for_bit(tmp_path):
    atoms = copper()
    dyn = npt(atoms)
    with Trajectory(tmp_path / 'run.traj', 'w', atoms) as traj:
        dyn.attach(traj.write, interval=10)
        dyn.run(10)
        dyn.write_buffer(tmp_path / 'buffer.npz')
    state = dyn.engine.snapshot()
    frame = read(tmp_path / 'run.traj', index=-1)
    frame.calc = EMT()
    again = npt(frame, seed=None, buffer=tmp_path / 'buffer.npz')
    assert again.seed == dyn.seed
    assert again.get_time() == dyn.get_time()
    resumed = again.engine.snapshot()
    for name in state:
        assert np.array_equal(resumed[name], state[name]), name
    for a, b in zip(shown(frame), shown(atoms)):
        assert np.array_equal(a, b)
    dyn.observers.clear()
    dyn.run(8)
    again.run(8)
    assert_same_counts(again, dyn)
    # The resumed run goes back past the frame to the first run's start.
    again.reverse()
    again.run(18)
    assert again.get_time() == 0.0
    # Not under other dynamics: the steps behind the frame would retrace
    # elsewhere.
    frame = read(tmp_path / 'run.traj', index=-1)
    frame.calc = EMT()
    with pytest.raises(ValueError, match='written with pressure_au'):
        npt(frame, seed=None, buffer=tmp_path / 'buffer.npz',
            pressure_au=2.0 * units.GPa)


def test_a_frame_alone_resumes_the_exact_state(tmp_path):
    atoms = copper()
    dyn = npt(atoms)
    dyn.run(6)
    path = tmp_path / 'frame.traj'
    with Trajectory(path, 'w') as traj:
        traj.write(atoms)
    frame = read(path)
    frame.calc = EMT()
    with pytest.warns(AnchorMovedWarning, match='without the buffer file'):
        again = npt(frame, seed=None)
    assert_same_counts(again, dyn)
    assert_back(again, again.engine.snapshot(), shown(frame))
    out_and_back(again, 20)
    assert again.get_time() == dyn.get_time()


def test_a_frame_equilibrated_since_is_a_quiet_new_start(tmp_path):
    # ASE's Langevin moved the frame's atoms: a new run, reference cell
    # the frame's, clock at 0, nothing said (as for every dynamics).
    from ase.md.langevin import Langevin
    atoms = copper()
    npt(atoms).run(6)
    path = tmp_path / 'frame.traj'
    with Trajectory(path, 'w') as traj:
        traj.write(atoms)
    frame = read(path)
    frame.calc = EMT()
    Langevin(frame, 2 * units.fs, temperature_K=300, friction=0.01,
             fixcm=False, rng=np.random.default_rng(0)).run(3)
    with warnings.catch_warnings():
        warnings.simplefilter('error', AnchorMovedWarning)
        again = npt(frame)
    assert again.get_time() == 0.0
    assert np.array_equal(again.reference_cell, frame.cell[:])
    out_and_back(again, 10)


@pytest.mark.parametrize('name', ['tchain', 'pchain', 'tloop', 'ploop'])
def test_arguments_of_ase_chains_are_refused_with_the_translation(name):
    atoms = copper()
    with pytest.raises(TypeError, match=f'leave {name} out'):
        npt(atoms, **{name: 3})


def test_a_cell_filter_is_refused_naming_the_npt_class():
    from ase.filters import FrechetCellFilter
    atoms = copper()
    with pytest.raises(TypeError, match='ReversibleIsotropicNPT'):
        npt(FrechetCellFilter(atoms))


def test_a_calculator_without_stress_is_refused():
    from ase_reversible import SoftenedGravity
    atoms = copper()
    atoms.calc = SoftenedGravity()
    with pytest.raises(ValueError, match='needs the stress'):
        npt(atoms, force_purity='trust')


def test_a_cluster_and_constraints_are_refused():
    from ase.constraints import FixAtoms
    atoms = copper()
    atoms.pbc = (True, True, False)
    with pytest.raises(ValueError, match='periodic in all three'):
        npt(atoms)
    atoms = copper()
    atoms.set_constraint(FixAtoms([0]))
    with pytest.raises(UnsupportedConstraintError, match='no constraints'):
        npt(atoms)


def test_a_cell_set_between_runs_is_refused_and_put_back():
    dyn = npt(copper())
    dyn.run(4)
    state, seen = dyn.engine.snapshot(), shown(dyn.atoms)
    dyn.atoms.set_cell(seen[2] * 1.01, scale_atoms=True)
    with pytest.raises(ValueError, match='moves the cell itself'):
        dyn.run(1)
    assert_back(dyn, state, seen, emptied=False)
    dyn.reverse()
    dyn.run(4)
    assert dyn.get_time() == 0.0


def test_momenta_set_between_runs_are_taken_with_the_cell_kept():
    dyn = npt(copper())
    dyn.run(4)
    cell = dyn.atoms.cell.array.copy()
    dyn.atoms.set_momenta(dyn.atoms.get_momenta() * 0.5)
    with pytest.warns(AnchorMovedWarning, match='Positions or momenta'):
        dyn.run(3)
    state, seen = dyn.engine.snapshot(), shown(dyn.atoms)
    assert not np.array_equal(seen[2], cell)
    dyn.run(10)
    dyn.reverse()
    dyn.run(10)
    assert_back(dyn, state, seen, emptied=False)


def test_a_calculator_without_stress_set_between_runs_is_refused():
    from ase_reversible import SoftenedGravity
    dyn = npt(copper())
    dyn.run(2)
    state, seen = dyn.engine.snapshot(), shown(dyn.atoms)
    emt = dyn.atoms.calc
    dyn.atoms.calc = SoftenedGravity()
    with pytest.raises(ValueError, match='needs the stress'):
        dyn.run(1)
    dyn.atoms.calc = emt
    dyn.run(0)
    assert_back(dyn, state, seen, emptied=False)


def test_a_collapsing_cell_stops_the_run_at_a_reversible_state():
    atoms = copper()
    with pytest.warns(UserWarning, match='is 400 GPa'):
        dyn = npt(atoms, pressure_au=400 * units.GPa, pdamp=200 * units.fs,
                  energy_check=0)
    state, seen = dyn.engine.snapshot(), shown(atoms)
    with pytest.raises(UnstableIntegrationError, match='cell collapsed'):
        dyn.run(200)
    taken = dyn.nsteps
    lam = dyn.barostat_position
    assert taken > 5 and LAMBDA_MIN < lam < 1
    assert np.array_equal(atoms.cell.array, dyn.reference_cell * lam)
    dyn.reverse()
    dyn.run(taken)
    assert_back(dyn, state, seen)


class WholeRun:
    """L(x0, p0) = <a, x_T> + <b, p_T> over a fresh run of ``steps``."""

    def __init__(self, steps, seed=5, build=None):
        self.build = npt if build is None else build
        self.steps = steps
        self.a_nc, self.b_nc = np.random.default_rng(seed).normal(
            size=(2, 32, 3))

    def dynamics(self, dx_nc=0.0, dp_nc=0.0):
        atoms = copper()
        atoms.positions = atoms.positions + dx_nc
        atoms.set_momenta(atoms.get_momenta() + dp_nc)
        # Fine quanta: a finite difference of a whole run sees the
        # rounding as noise.
        return self.build(atoms, energy_check=0, position_quantum=2.0**-44,
                          momentum_quantum=2.0**-46)

    def __call__(self, dx_nc=0.0, dp_nc=0.0):
        dyn = self.dynamics(dx_nc, dp_nc)
        dyn.run(self.steps)
        atoms = dyn.atoms
        return float(np.sum(self.a_nc * atoms.positions)
                     + np.sum(self.b_nc * atoms.get_momenta()))


@pytest.mark.parametrize('kind', ['isotropic', 'full'])
def test_gradients_match_whole_run_finite_differences(kind):
    loss = WholeRun(steps=3, build=npt if kind == 'isotropic' else
                    lambda atoms, **kw: full(atoms, **kw))
    dyn = loss.dynamics()
    start, seen = dyn.engine.snapshot(), shown(dyn.atoms)
    dyn.run(loss.steps)
    grads = dyn.backpropagate(loss.steps, loss.a_nc, loss.b_nc)
    # The retrace ends at the start, bit for bit.
    assert_back(dyn, start, seen)
    assert set(grads.thermostat) == {'lambda', 'p_lambda'}
    assert grads.products == 2 * loss.steps
    u_nc, v_nc = np.random.default_rng(6).normal(size=(2, 32, 3))
    # The step is large against the jitter of the piston's friction (its
    # buffer's digits, 2**-20 of the spread of p_lambda a step), small
    # against the curvature.
    e = 1e-3
    zero = np.zeros((32, 3))
    for grad, dx, dp, w in ((grads.positions, u_nc, zero, u_nc),
                            (grads.momenta, zero, v_nc, v_nc)):
        fd = (loss(e * dx, e * dp) - loss(-e * dx, -e * dp)) / (2 * e)
        assert float(np.sum(grad * w)) == pytest.approx(fd, rel=1e-4)


def test_parameter_gradients_are_refused():
    dyn = npt(copper())
    dyn.run(2)
    with pytest.raises(NotImplementedError, match='potential parameters'):
        dyn.backpropagate(2, grad_positions=np.ones((32, 3)),
                          parameters=('sigma',))


# One case in the quick tier (1 s each), both in the long one.
@pytest.mark.parametrize('cls', tiered([ReversibleIsotropicNPT, ReversibleNPT],
                                       quick=[ReversibleNPT]))
def test_the_extended_energy_errs_by_the_square_of_the_time_step(
        cls, monkeypatch):
    """With no friction, the conserved energy moves by the splitting's
    error only, which halving the time step divides by about four: a
    force or push inconsistent with the Hamiltonian would not shrink."""
    from ase_reversible.md.npt import isotropic
    monkeypatch.setattr(isotropic, 'PISTON_FRICTION', False)
    errors = []
    for dt in (2.5 * units.fs, 1.25 * units.fs):
        atoms = copper()
        dyn = cls(atoms, dt, 300, 1.0 * units.GPa, 1e9 * units.fs,
                  100 * units.fs, seed=1, energy_check=0)
        e0 = dyn.get_conserved_energy()
        moved = []
        for _ in range(4):
            dyn.run(round(15 * units.fs / dt))
            moved.append(abs(dyn.get_conserved_energy() - e0))
        errors.append(max(moved))
    assert 0 < errors[1] < 0.35 * errors[0] < 5e-3


@SLOW
def test_a_long_run_goes_out_and_back():
    atoms = copper_bulk((3, 3, 3), 300)
    atoms.calc = asap_emt()
    dyn = npt(atoms, pdamp=200 * units.fs)
    out_and_back(dyn, 2500)
    assert dyn.force_purity.mode in ('sorted', 'guarded', 'trust')


@SLOW
def test_a_long_full_cell_run_goes_out_and_back():
    atoms = copper_bulk((3, 3, 3), 300)
    atoms.calc = asap_emt()
    out_and_back(full(atoms, pdamp=200 * units.fs), 2500, full_cell=True)


def test_guarded_roundings_recompute_cleanly_and_stay_exact(monkeypatch):
    # A wide guard band and a fine quantum of p_lambda: the kicks and the
    # piston's kicks come near a tie often, and each is then recomputed
    # from a clean neighbour list.
    from ase_reversible.md.npt import system as module
    monkeypatch.setattr(module, 'TARGET_CLEAN_RATE', 1e9)
    cleaned = []
    clean = module.ScaledKick.clean_stress_trace
    monkeypatch.setattr(module.ScaledKick, 'clean_stress_trace',
                        lambda kick: cleaned.append(1) or clean(kick))
    atoms = copper_bulk((2, 2, 2), 300)
    atoms.calc = asap_emt()
    dyn = npt(atoms, force_purity='guarded', force_noise=2.0**-30,
              momentum_quantum=2.0**-32)
    out_and_back(dyn, 30)
    assert len(cleaned) > 0
    assert dyn.force_purity.clean_recomputations > len(cleaned)


# -- ReversibleNPT: the whole cell --------------------------------------------

def full(atoms, **kwargs):
    settings = dict(temperature_K=300, pressure_au=1.0 * units.GPa,
                    tdamp=50 * units.fs, pdamp=100 * units.fs, seed=7)
    settings.update(kwargs)
    return ReversibleNPT(atoms, DT, **settings)


def test_full_cell_copper_emt_runs_out_and_back():
    out_and_back(full(copper()), 30, full_cell=True)


def test_full_cell_asap3_emt_runs_out_and_back():
    atoms = copper_bulk((2, 2, 2), 300)
    atoms.calc = asap_emt()  # skips where asap3 is missing
    out_and_back(full(atoms), 30, full_cell=True)


def test_full_cell_piston_force_is_minus_the_energy_derivative():
    """Each of the six entries: ``force + J = -dU/dM_ab`` at fixed scaled
    positions, by central differences of the energy under ``M -> M + d
    E_ab`` (positions and cell together)."""
    atoms = copper()
    dyn = full(atoms, pressure_au=0.0)
    s = dyn.system
    # A deformation well away from the identity, so that M^-T, M^-1 and
    # the identity give different forces.
    m = np.array([[1.02, 0, 0], [0.05, 0.98, 0], [-0.04, 0.03, 1.01]])
    s.lam.reset(np.rint(m[ROWS, COLUMNS] / s.lam.quantum))
    s.show()
    m = s.matrices()[0]
    force = CellVirial(s).force(s.kick.stress())
    force[2] += s.kT / m[1, 1]
    force[5] += 2 * s.kT / m[2, 2]
    probe = atoms.copy()
    probe.calc = EMT()
    rho, cell0 = s.x.floats.copy(), s.cell0
    d = 1e-6
    for k, (a, b) in enumerate(zip(ROWS, COLUMNS)):
        energies = []
        for sign in (1, -1):
            moved = m.copy()
            moved[a, b] += sign * d
            probe.set_cell(cell0 @ moved, scale_atoms=False)
            probe.positions = rho @ moved
            energies.append(probe.get_potential_energy())
        derivative = (energies[0] - energies[1]) / (2 * d)
        assert force[k] == pytest.approx(-derivative, rel=1e-4, abs=1e-4)
    assert np.abs(force).max() > 1.0  # eV: a test that could fail


def test_full_cell_frame_and_buffer_resume_bit_for_bit(tmp_path):
    atoms = copper()
    dyn = full(atoms)
    dyn.run(8)
    dyn.write_buffer(tmp_path / 'buffer.npz')
    with Trajectory(tmp_path / 'frame.traj', 'w') as traj:
        traj.write(atoms)
    frame = read(tmp_path / 'frame.traj')
    frame.calc = EMT()
    again = full(frame, seed=None, buffer=tmp_path / 'buffer.npz')
    assert_same_counts(again, dyn)
    dyn.run(6)
    again.run(6)
    assert_same_counts(again, dyn)
    again.reverse()
    again.run(14)
    assert again.get_time() == 0.0


def test_full_cell_refusals():
    atoms = copper()
    atoms.set_cell([[7.2, 0.1, 0], [0, 7.2, 0], [0, 0, 7.2]],
                   scale_atoms=True)
    with pytest.raises(ValueError, match='standard_form'):
        full(atoms)
    with pytest.raises(TypeError, match="ASE's MTKNPT"):
        full(copper(), pchain=3)
    dyn = full(copper())
    dyn.run(2)
    with pytest.raises(NotImplementedError, match='potential parameters'):
        dyn.backpropagate(2, grad_positions=np.ones((32, 3)),
                          parameters=('sigma',))


def test_a_frame_whose_stress_differs_here_is_warned_about(tmp_path):
    from ase_reversible import MachineChangedWarning
    atoms = copper()
    dyn = npt(atoms)
    dyn.run(5)
    with Trajectory(tmp_path / 'frame.traj', 'w') as traj:
        traj.write(atoms)
    frame = read(tmp_path / 'frame.traj')
    assert len(frame.info['reversible']['npt']['stress']) == 8
    frame.calc = EMT()
    with warnings.catch_warnings():
        warnings.simplefilter('error', MachineChangedWarning)
        assert npt(frame, seed=None).forces_match_record is True
    frame = read(tmp_path / 'frame.traj')
    frame.info['reversible']['npt']['stress'] = '00000000'
    frame.calc = EMT()
    with pytest.warns(MachineChangedWarning, match='stress at this restart'):
        again = npt(frame, seed=None)
    assert again.forces_match_record is False
    assert_same_counts(again, dyn)


@SLOW
def test_a_frame_resumed_on_another_blas_warns_of_its_stress(tmp_path):
    """ASE's EMT sums its stress with a BLAS product: on an emulated
    machine with another OpenBLAS core type the forces keep their bits and
    the stress does not, and the resumed ReversibleNPT says so."""
    from machines import emulation_works, run_leg
    if not emulation_works(tmp_path):
        pytest.skip('the emulated machines compute alike here')
    write = '''
from ase import units
from ase.calculators.emt import EMT
from ase.io import write
from ase_reversible import ReversibleNPT
from ase_reversible.app.systems import copper_bulk
atoms = copper_bulk((2, 2, 2), 300)
atoms.calc = EMT()
ReversibleNPT(atoms, 5 * units.fs, 300, units.GPa, 50 * units.fs,
              100 * units.fs, seed=7).run(5)
write('frame.traj', atoms)
'''
    resume = '''
import warnings
from ase import units
from ase.calculators.emt import EMT
from ase.io import read
from ase_reversible import ReversibleNPT
frame = read('frame.traj')
frame.calc = EMT()
with warnings.catch_warnings(record=True) as seen:
    warnings.simplefilter('always')
    dyn = ReversibleNPT(frame, 5 * units.fs, 300, units.GPa, 50 * units.fs,
                        100 * units.fs)
print(dyn.forces_match_record, [str(w.message)[:40] for w in seen])
'''
    run_leg('avx2', write, tmp_path)
    # Resumed without its buffer file the frame warns that the way back
    # stops there, on any machine; of the stress only on another one.
    here = run_leg('avx2', resume, tmp_path)
    assert here.startswith('True') and 'The stress at this restart' not in here
    there = run_leg('sse4', resume, tmp_path)
    assert there.startswith('False') and 'The stress at this restart' in there


@pytest.mark.parametrize('build', [npt, full])
def test_a_step_back_past_the_anchor_is_refused_naming_the_class(build):
    from ase_reversible import RetraceLimitError
    dyn = build(copper())
    state, seen = dyn.engine.snapshot(), shown(dyn.atoms)
    dyn.reverse()
    with pytest.raises(RetraceLimitError, match=type(dyn).__name__):
        dyn.run(1)
    assert_back(dyn, state, seen)


def test_a_pressure_that_looks_like_gpa_or_bar_is_warned_about():
    atoms = copper()
    with pytest.warns(UserWarning, match=r'for 1 GPa pass 1 \* ase.units.GPa'):
        ReversibleIsotropicNPT(atoms, DT, temperature_K=300, pressure_au=1.0,
                               tdamp=100 * DT, pdamp=1000 * DT, seed=1)
