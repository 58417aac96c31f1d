"""TorchCalculator: PyTorch energy models run out and back bit for bit, and
their vector-Jacobian products against finite differences."""

import pytest

torch = pytest.importorskip('torch', reason='ase_reversible.torch needs '
                            "PyTorch (pip install 'torch==2.13.0')")

import warnings  # noqa: E402

import numpy as np  # noqa: E402
from ase import units  # noqa: E402

import ase_reversible  # noqa: E402
from ase_reversible import (AnchorMovedWarning, ReversibleLangevin,  # noqa: E402
                            ReversibleVerlet)
from ase_reversible.torch import (LennardJones, PairMLP,  # noqa: E402
                                  TorchCalculator)

from calculator_conformance import CalculatorConformance  # noqa: E402
from conftest import AR_EPSILON, AR_SIGMA, DT  # noqa: E402
from conftest import argon_bulk, argon_cluster  # noqa: E402
from exactness import (assert_runs_back, assert_same_state,  # noqa: E402
                       snapshot, weight_gradients_of_displacement)

MLP_CUTOFF = 7.0   # Å


def mlp_calc(**kwargs):
    model = PairMLP(cutoff=MLP_CUTOFF)
    return TorchCalculator(model, MLP_CUTOFF, **kwargs)


def lj_calc(**kwargs):
    model = LennardJones(AR_EPSILON, AR_SIGMA)
    return TorchCalculator(model, model.rc, **kwargs)


def ar13(calc):
    atoms = argon_cluster(2, 60)
    atoms.rattle(0.05, seed=4)
    atoms.calc = calc
    return atoms


def ar32(calc):
    atoms = argon_bulk((2, 2, 2), 60)
    atoms.rattle(0.05, seed=5)
    atoms.calc = calc
    return atoms


MAKERS = {'mlp': mlp_calc, 'lj': lj_calc}
SYSTEMS = {'ar13': ar13, 'ar32': ar32}


# -- agreement with the package's numpy Lennard-Jones ----------------------

@pytest.mark.parametrize('system', sorted(SYSTEMS))
def test_torch_lj_matches_the_numpy_one(system):
    atoms = SYSTEMS[system](lj_calc())
    model = atoms.calc.model
    ref = atoms.copy()
    ref.calc = ase_reversible.LennardJones(
        epsilon=AR_EPSILON, sigma=AR_SIGMA, rc=model.rc, ro=model.ro)
    e, e_ref = atoms.get_potential_energy(), ref.get_potential_energy()
    assert abs(e - e_ref) < 1e-12 * abs(e_ref)
    f, f_ref = atoms.get_forces(), ref.get_forces()
    assert np.abs(f - f_ref).max() < 1e-12 * np.abs(f_ref).max()
    v_nc = np.random.default_rng(0).normal(size=f.shape)
    dx_nc, dtheta = atoms.calc.vector_jacobian_product(
        atoms, v_nc, ['epsilon', 'sigma'])
    hv_nc = ref.calc.hessian_vector_product(ref, v_nc)
    assert np.abs(dx_nc + hv_nc).max() < 1e-12 * np.abs(hv_nc).max()
    for name in ('epsilon', 'sigma'):
        expected = np.vdot(ref.calc.force_parameter_derivative(ref, name),
                           v_nc)
        assert isinstance(dtheta[name], float)
        assert abs(dtheta[name] - expected) < 1e-12 * abs(expected)


# -- products against central differences ----------------------------------

def forces_at(atoms, x_nc):
    atoms.positions = x_nc
    return atoms.get_forces()


@pytest.mark.parametrize('kind', sorted(MAKERS))
def test_product_matches_finite_differences(kind):
    atoms = ar13(MAKERS[kind]())
    calc = atoms.calc
    rng = np.random.default_rng(1)
    x0_nc = atoms.get_positions()
    f0_nc = atoms.get_forces()
    v_nc = rng.normal(size=x0_nc.shape)
    names = calc.differentiable_parameters
    dx_nc, dtheta = calc.vector_jacobian_product(atoms, v_nc, names)
    # Positions and results untouched by the product.
    assert np.array_equal(atoms.positions, x0_nc)
    assert calc.check_state(atoms) == []
    assert np.array_equal(atoms.get_forces(), f0_nc)
    # Positions: (dF/dx)^T v = (dF/dx) v (symmetric), along v.
    h = 1e-5
    fd_nc = (forces_at(atoms, x0_nc + h * v_nc)
             - forces_at(atoms, x0_nc - h * v_nc)) / (2 * h)
    atoms.positions = x0_nc
    assert np.abs(dx_nc - fd_nc).max() < 1e-7 * np.abs(dx_nc).max()
    # Parameters: along a random direction u in parameter space,
    # u . (dF/dθ)^T v = v . d/de F(θ + e u).
    u = {name: rng.normal(size=np.shape(value))
         for name, value in calc.parameter_values().items()}
    theta0 = calc.parameter_values()
    exact = sum(float(np.vdot(u[name], dtheta[name])) for name in names)

    def forces_with(e):
        calc.set_parameter_values({name: theta0[name] + e * u[name]
                                   for name in names})
        return atoms.get_forces()

    e = 1e-6 * max(abs(np.concatenate(
        [np.ravel(t) for t in theta0.values()])).max(), 1e-3)
    fd = np.vdot(v_nc, (forces_with(e) - forces_with(-e)) / (2 * e))
    calc.set_parameter_values(theta0)
    assert abs(exact - fd) < 1e-6 * abs(exact)
    assert np.array_equal(atoms.get_forces(), f0_nc)


def test_pair_mlp_fits_a_pair_curve_deterministically():
    def lj(r):
        s6 = (AR_SIGMA / r) ** 6
        return 4 * AR_EPSILON * (s6 * s6 - s6)

    r = np.linspace(3.2, MLP_CUTOFF, 200)
    models = [PairMLP(cutoff=MLP_CUTOFF) for _ in range(2)]
    before = np.sqrt(np.mean((models[0].pair_energy(
        torch.from_numpy(r)).detach().numpy() - lj(r)) ** 2))
    errors = [m.fit_pair_curve(lj, 3.2, steps=200) for m in models]
    # Measured: 6.4e-3 eV RMS before, 2.9e-4 after 200 steps (the well is
    # 1.04e-2 deep).
    assert errors[0] < 5e-4 < before / 10
    assert errors[0] == errors[1]
    for a, b in zip(*(m.parameters() for m in models)):
        assert torch.equal(a, b)


# -- purity and exact reversal ----------------------------------------------

@pytest.mark.parametrize('kind', sorted(MAKERS))
def test_forces_are_pure_and_the_same_with_one_and_two_threads(kind):
    atoms = ar32(MAKERS[kind]())
    x0_nc = atoms.get_positions()
    f0_nc = atoms.get_forces()
    rng = np.random.default_rng(3)
    for scale in (0.05, 1.0):
        atoms.positions = x0_nc + rng.normal(0.0, scale, x0_nc.shape)
        atoms.get_forces()
        atoms.positions = x0_nc
        assert np.array_equal(atoms.get_forces(), f0_nc)
    two = atoms.copy()
    two.calc = MAKERS[kind](threads=2)
    assert np.array_equal(two.get_forces(), f0_nc)


def test_a_product_from_the_kept_graph_is_the_fresh_one_bit_for_bit():
    # After a first product the force calls keep their graph for the next
    # product at the same positions: same bits as a fresh pass, and the
    # forces are those of a calculator that keeps nothing.
    atoms = ar32(mlp_calc())
    calc = atoms.calc
    names = calc.differentiable_parameters
    v_nc = np.random.default_rng(8).normal(size=(len(atoms), 3))
    calc.vector_jacobian_product(atoms, v_nc, names)
    atoms.positions[0, 0] += 0.01
    f_nc = atoms.get_forces()
    assert calc._graph is not None
    kept = calc.vector_jacobian_product(atoms, v_nc, names)
    fresh_atoms = atoms.copy()
    fresh_atoms.calc = mlp_calc()
    assert np.array_equal(fresh_atoms.get_forces(), f_nc)
    fresh = fresh_atoms.calc.vector_jacobian_product(fresh_atoms, v_nc, names)
    assert np.array_equal(kept[0], fresh[0])
    assert all(np.array_equal(kept[1][n], fresh[1][n]) for n in names)
    # A weight changed in place after the force call: not from the graph.
    atoms.get_forces()
    with torch.no_grad():
        calc.model.mlp[0].bias.data += 1e-3
    changed = calc.vector_jacobian_product(atoms, v_nc, names)
    fresh_atoms.calc.model.mlp[0].bias.data += 1e-3
    again = fresh_atoms.calc.vector_jacobian_product(fresh_atoms, v_nc, names)
    assert np.array_equal(changed[0], again[0])
    assert not np.array_equal(changed[0], kept[0])


def test_the_callers_torch_settings_are_restored():
    atoms = ar13(mlp_calc(threads=2))
    threads = torch.get_num_threads()
    deterministic = torch.are_deterministic_algorithms_enabled()
    atoms.get_forces()
    atoms.calc.vector_jacobian_product(atoms, np.ones((13, 3)))
    assert torch.get_num_threads() == threads
    assert torch.are_deterministic_algorithms_enabled() == deterministic


@pytest.mark.parametrize('kind', sorted(MAKERS))
@pytest.mark.parametrize('system', sorted(SYSTEMS))
def test_verlet_runs_out_and_back_bit_for_bit(kind, system):
    atoms = SYSTEMS[system](MAKERS[kind]())
    dyn = ReversibleVerlet(atoms, DT)
    assert dyn.force_purity.mode == 'trust'
    assert_runs_back(dyn, 30)


@pytest.mark.parametrize('kind', sorted(MAKERS))
def test_langevin_runs_out_and_back_bit_for_bit(kind):
    atoms = ar13(MAKERS[kind]())
    dyn = ReversibleLangevin(atoms, DT, temperature_K=60,
                             friction=0.02 / units.fs, seed=1)
    assert_runs_back(dyn, 30)


# -- weights changed between runs -------------------------------------------

def test_an_optimiser_step_moves_the_anchor_and_reversal_leads_there():
    atoms = ar13(mlp_calc())
    model = atoms.calc.model
    dyn = ReversibleVerlet(atoms, DT)
    with warnings.catch_warnings():
        warnings.simplefilter('error', AnchorMovedWarning)
        dyn.run(10)
        dyn.run(5)   # no change: no warning
    # A training step between two runs.
    optimiser = torch.optim.SGD(model.parameters(), lr=1e-3)
    x = torch.from_numpy(atoms.get_positions())
    edge = torch.tensor([[0, 1], [1, 0]])
    loss = model(x, None, None, edge, torch.zeros((2, 3),
                                                  dtype=torch.float64))
    loss.backward()
    optimiser.step()
    anchor = snapshot(atoms)
    with pytest.warns(AnchorMovedWarning, match='weights'):
        dyn.run(15)
    dyn.reverse()
    with warnings.catch_warnings():
        warnings.simplefilter('error', AnchorMovedWarning)
        dyn.run(15)
    assert_same_state(atoms, anchor)


def test_gradients_reach_a_torch_optimiser_and_its_step_is_taken():
    atoms = ar13(mlp_calc())
    calc, model = atoms.calc, atoms.calc.model
    dyn = ReversibleVerlet(atoms, DT)
    g = weight_gradients_of_displacement(dyn, 10)
    for name, p in model.named_parameters():
        assert p.grad.dtype == torch.float64
        assert np.array_equal(p.grad.numpy(), g.parameters[name])
    before = calc.parameter_values()
    torch.optim.Adam(model.parameters(), lr=1e-3).step()
    assert any(not np.array_equal(before[n], v)
               for n, v in calc.parameter_values().items())
    with pytest.warns(AnchorMovedWarning, match='weights'):
        dyn.run(3)
    name = calc.differentiable_parameters[0]
    with pytest.raises(ValueError, match='shape'):
        calc.assign_gradients({name: np.zeros(3)})


def test_an_edit_through_data_is_seen():
    atoms = ar13(mlp_calc())
    calc = atoms.calc
    f_nc = atoms.get_forces()
    fingerprint = calc.parameters['weights']
    # Not seen by tensor._version.
    calc.model.mlp[0].weight.data[:, 8] += 1e-3   # basis near 3.8 Å
    assert calc.parameters['weights'] != fingerprint
    assert calc.check_state(atoms) == ['weights']
    assert not np.array_equal(atoms.get_forces(), f_nc)
    # A plain setting of a module is part of the fingerprint too.
    fingerprint = calc.parameters['weights']
    calc.model.energy_scale *= 2
    assert calc.parameters['weights'] != fingerprint
    f_nc = atoms.get_forces()
    calc.model.energy_scale /= 2
    assert not np.array_equal(atoms.get_forces(), f_nc)


# -- refusals and the protocol's checks -------------------------------------

def test_float32_models_are_refused():
    with pytest.raises(TypeError, match=r'model\.double\(\)'):
        TorchCalculator(PairMLP(cutoff=MLP_CUTOFF).float(), MLP_CUTOFF)
    calc = mlp_calc()
    atoms = ar13(calc)
    calc.model.float()   # after construction: refused at the next call
    with pytest.raises(TypeError, match=r'model\.double\(\)'):
        atoms.get_forces()


def test_bad_arguments_are_refused_with_what_to_do():
    calc = mlp_calc()
    atoms = ar13(calc)
    with pytest.raises(ValueError, match='available'):
        calc.vector_jacobian_product(atoms, np.zeros((13, 3)), ['nope'])
    with pytest.raises(ValueError, match='shape'):
        calc.vector_jacobian_product(atoms, np.zeros((12, 3)))
    with pytest.raises(ValueError, match='available'):
        calc.parameter_values(['nope'])
    before = calc.parameter_values()
    with pytest.raises(ValueError, match='shape'):
        calc.set_parameter_values({'mlp.0.bias': np.zeros(3)})
    with pytest.raises(ValueError, match='NaN'):
        calc.set_parameter_values({'mlp.0.bias': np.full(64, np.nan),
                                   'mlp.2.bias': np.zeros(44)})
    after = calc.parameter_values()
    assert all(np.array_equal(before[k], after[k]) for k in before)
    with pytest.raises(ValueError, match="model's cutoff"):
        TorchCalculator(PairMLP(cutoff=MLP_CUTOFF), MLP_CUTOFF - 1)
    # A refused set changes nothing.
    f_nc = atoms.get_forces()
    with pytest.raises(ValueError, match="model's cutoff"):
        calc.set(cutoff=MLP_CUTOFF - 1)
    assert calc.parameters['cutoff'] == MLP_CUTOFF
    assert calc.check_state(atoms) == []
    assert np.array_equal(atoms.get_forces(), f_nc)
    with pytest.raises(TypeError, match='torch.nn.Module'):
        TorchCalculator(lambda x: x, 5.0)


def test_import_ase_reversible_stays_without_torch():
    import subprocess
    import sys
    code = ('import sys, ase_reversible; '
            'print("torch" in sys.modules)')
    out = subprocess.run([sys.executable, '-c', code], capture_output=True,
                         text=True, check=True).stdout.strip()
    assert out == 'False'


# -- the shared calculator checks -------------------------------------------

class TestTorchLennardJones(CalculatorConformance):
    systems = {'ar13': lambda: ar13(None)}
    timestep = DT
    reversal_steps = 30
    gradient_tolerance = 1e-8
    hessian_tolerance = 1e-7
    bad_parameters = [({'cutoff': -1.0}, ValueError, 'cutoff'),
                      ({'cutoff': 'far'}, TypeError, 'cutoff'),
                      ({'cutoff': 5.0}, ValueError, "model's cutoff")]

    def make_calc(self, **parameters):
        model = LennardJones(AR_EPSILON, AR_SIGMA)
        return TorchCalculator(model, **{'cutoff': model.rc, **parameters})

    def test_force_parameter_derivatives_match_finite_differences(self):
        pytest.skip("reads the parameters from calc.parameters and sets them "
                    "with calc.set; a model's are tensors, checked by "
                    'test_vector_jacobian_product_matches_finite_differences')


# -- the reversible adjoint through a user's own model ----------------------

class MorseWithCorrection(torch.nn.Module):
    """What a user might write: a Morse pair potential plus a learned
    polynomial correction, both cut off smoothly at ``cutoff`` (Å)."""

    def __init__(self, cutoff=7.5):
        super().__init__()
        self.cutoff = cutoff
        self.depth = torch.nn.Parameter(torch.tensor(0.0104,
                                                     dtype=torch.float64))
        self.alpha = torch.nn.Parameter(torch.tensor(1.6,
                                                     dtype=torch.float64))
        self.r0 = torch.nn.Parameter(torch.tensor(3.82, dtype=torch.float64))
        self.coefficients = torch.nn.Parameter(torch.tensor(
            [2e-3, -4e-3, 1e-3, 5e-4], dtype=torch.float64))

    def forward(self, positions, numbers, cell, edge_index, edge_shift):
        i, j = edge_index
        d = positions[j] - positions[i] + edge_shift
        r = torch.sqrt((d * d).sum(dim=1))
        e = torch.exp(-self.alpha * (r - self.r0))
        morse = self.depth * ((1 - e) ** 2 - 1)
        t = r / self.cutoff
        powers = torch.stack([t ** k for k in range(4)], dim=1)
        fc = (1 - t * t) ** 3
        # Both directions of every pair are in the list: half of each.
        return 0.5 * ((morse + powers @ self.coefficients) * fc).sum()


#: Fine quanta: a finite difference of whole runs sees rounding as noise.
FINE = {'position_quantum': 2.0**-44, 'momentum_quantum': 2.0**-46}


def user_atoms(temperature_K=40):
    atoms = argon_cluster(2, temperature_K, seed=2)
    model = MorseWithCorrection()
    atoms.calc = TorchCalculator(model, model.cutoff)
    return atoms


def adjoint_against_float_verlet(steps, relative_steps):
    """``dL/dθ . u`` from backpropagate against central differences of a
    float ASE VelocityVerlet run from the same state, L = <a, x_T>;
    returns the relative errors at each finite-difference step."""
    from ase.md.verlet import VelocityVerlet
    atoms = user_atoms()
    calc = atoms.calc
    names = calc.differentiable_parameters
    rng = np.random.default_rng(6)
    a_nc = rng.normal(size=(len(atoms), 3))
    dyn = ReversibleVerlet(atoms, DT, energy_check=0, **FINE)
    start = snapshot(atoms)          # on the grid: the float run starts here
    dyn.run(steps)
    g = dyn.backpropagate(steps, a_nc, None, parameters=names)
    assert_same_state(atoms, start)
    # One product per kick but the last one retraced first, whose momentum
    # cotangent is zero (L depends on x_T alone).
    assert g.products == steps
    theta0 = calc.parameter_values()
    for name in names:
        assert np.shape(g.parameters[name]) == np.shape(theta0[name])
    u = {name: rng.normal(size=np.shape(theta0[name])) for name in names}
    exact = sum(float(np.vdot(u[n], g.parameters[n])) for n in names)

    def loss(e):
        run = atoms.copy()
        run.positions, _ = start
        run.set_momenta(start[1])
        model = MorseWithCorrection()
        other = TorchCalculator(model, model.cutoff)
        other.set_parameter_values({n: theta0[n] + e * u[n] for n in names})
        run.calc = other
        VelocityVerlet(run, DT).run(steps)
        return np.vdot(a_nc, run.positions)

    errors = []
    for h in relative_steps:
        fd = (loss(h) - loss(-h)) / (2 * h)
        errors.append(abs(exact - fd) / abs(exact))
    return errors


def test_backpropagate_through_a_users_model_quick():
    errors = adjoint_against_float_verlet(20, [1e-5])
    assert errors[0] < 1e-6, errors


def test_a_windowed_loss_along_the_run_spends_one_product_per_step():
    atoms = ar13(mlp_calc())
    calc = atoms.calc
    dyn = ReversibleVerlet(atoms, DT)
    start = snapshot(atoms)
    dyn.run(40)
    g = dyn.backpropagate(40, loss=lambda a, k: (a.get_positions(), None),
                          every=10, window=5,
                          parameters=calc.differentiable_parameters)
    assert_same_state(atoms, start)
    # Four windows of five steps (the loss at k = 0 reaches back no step).
    assert g.products == 20
    assert all(np.shape(g.parameters[n]) == np.shape(v) for n, v in
               calc.parameter_values().items())


@pytest.mark.slow
def test_backpropagate_through_a_users_model_matches_float_verlet():
    # u has entries ~1 against parameters of 1e-3 to 4.  Measured at 300
    # steps: relative errors 1.1e-3, 1.1e-5, 1.1e-7, 2.1e-9, 5.9e-9 at
    # h = 1e-3 ... 1e-7: the h**2 truncation until rounding of the loss
    # over h takes over below 1e-6.
    errors = adjoint_against_float_verlet(300, [1e-4, 1e-5, 1e-6])
    assert errors[2] < 1e-6, errors
    # Converging as h**2: each tenth of h cuts the error ~100-fold.
    assert errors[1] < errors[0] / 30 and errors[2] < errors[1] / 30, errors


@pytest.mark.slow
@pytest.mark.parametrize('dynamics', ['verlet', 'langevin'])
def test_larger_system_longer_run_out_and_back(dynamics):
    atoms = argon_bulk((3, 3, 3), 80, seed=3)     # 108 atoms
    atoms.calc = mlp_calc()
    if dynamics == 'verlet':
        dyn = ReversibleVerlet(atoms, DT, order=4)
    else:
        dyn = ReversibleLangevin(atoms, DT, temperature_K=80,
                                 friction=0.02 / units.fs, seed=2)
    assert_runs_back(dyn, 200)


# -- MACE, where mace-torch is installed --------------------------------------

def test_a_mace_model_runs_back_and_its_product_matches_differences(
        monkeypatch):
    # e3nn 0.4.4 loads its own constants file with torch.load, refused by
    # torch >= 2.6's weights-only default.
    monkeypatch.setenv('TORCH_FORCE_NO_WEIGHTS_ONLY_LOAD', '1')
    pytest.importorskip('e3nn', reason='MACE needs e3nn (pip install '
                        'mace-torch==0.3.16 e3nn==0.4.4)')
    pytest.importorskip(
        'mace.modules', reason='mace-torch is not installed (pip install '
        'mace-torch==0.3.16 e3nn==0.4.4)')
    from ase_reversible.torch.mace import MACEModel, random_mace
    model = random_mace((18,))
    wrapped = MACEModel(model)
    atoms = ar13(TorchCalculator(wrapped, wrapped.cutoff))
    calc = atoms.calc
    x0_nc = atoms.get_positions()
    v_nc = np.random.default_rng(0).normal(size=x0_nc.shape)
    dx_nc, dtheta = calc.vector_jacobian_product(
        atoms, v_nc, calc.differentiable_parameters)
    assert set(dtheta) == set(calc.differentiable_parameters)
    h = 1e-5
    fd_nc = (forces_at(atoms, x0_nc + h * v_nc)
             - forces_at(atoms, x0_nc - h * v_nc)) / (2 * h)
    atoms.positions = x0_nc
    assert np.abs(dx_nc - fd_nc).max() < 1e-7 * np.abs(dx_nc).max()
    assert_runs_back(ReversibleVerlet(atoms, DT), 10)


def test_atoms_without_neighbours_have_zero_forces_and_products():
    from ase import Atoms
    atoms = Atoms('Ar2', positions=[[0, 0, 0], [20.0, 0, 0]])
    atoms.set_momenta([[0.5, 0, 0], [0, 0.3, 0]])
    for make in (mlp_calc, lj_calc):
        atoms.calc = make()
        assert atoms.get_potential_energy() == 0.0
        assert not atoms.get_forces().any()
        dx_nc, dtheta = atoms.calc.vector_jacobian_product(
            atoms, np.ones((2, 3)), atoms.calc.differentiable_parameters)
        assert not dx_nc.any()
        assert not any(np.any(d) for d in dtheta.values())
    assert_runs_back(ReversibleVerlet(atoms, DT), 5)


def test_without_torch_the_import_says_how_to_install_it(monkeypatch):
    import importlib
    import sys
    for name in [m for m in sys.modules if m.startswith('ase_reversible.torch')]:
        monkeypatch.delitem(sys.modules, name)
    monkeypatch.setitem(sys.modules, 'torch', None)   # as if not installed
    with pytest.raises(ImportError, match=r"pip install 'torch==2\.13\.0'"):
        importlib.import_module('ase_reversible.torch')


# A run continued where torch picks other CPU kernels: torch reads
# ATEN_CPU_CAPABILITY once, when it starts, so each leg is a process.
TORCH_LEG = '''
import sys, warnings
import numpy as np
from ase import units
from ase.cluster import Icosahedron
from ase.io import read
from ase_reversible import ReversibleVerlet
from ase_reversible.torch import PairMLP, TorchCalculator
model = PairMLP(cutoff=7.0, seed=0).double()
calc = TorchCalculator(model, 7.0)
if sys.argv[1] == 'forces':
    atoms = read('run.traj', 0)
    atoms.calc = calc
    print(atoms.get_forces().tobytes().hex())
elif sys.argv[1] == 'out':
    atoms = Icosahedron('Ar', 2, latticeconstant=5.26)
    atoms.center(vacuum=8.0)
    atoms.set_momenta(np.random.default_rng(0).normal(0, 0.3, (13, 3)))
    atoms.calc = calc
    ReversibleVerlet(atoms, 5 * units.fs, trajectory='run.traj').run(40)
else:
    atoms = read('run.traj', -1)
    atoms.calc = calc
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter('always')
        dyn = ReversibleVerlet(atoms, 5 * units.fs)
    print(sorted({type(w.message).__name__ for w in caught}))
'''


@pytest.mark.slow
def test_a_run_continued_with_other_torch_kernels_is_not_silent(tmp_path):
    """PairMLP forces come out in other bits when torch starts with
    ATEN_CPU_CAPABILITY=default (no SIMD) than with this CPU's kernels;
    the restart record's machine section must say so on resume."""
    import subprocess
    import sys
    from machines import machine_env
    script = tmp_path / 'leg.py'
    script.write_text(TORCH_LEG)

    def leg(kind, **env):
        done = subprocess.run(
            [sys.executable, str(script), kind], cwd=tmp_path,
            env={**machine_env('native'), **env}, capture_output=True,
            text=True, timeout=300)
        assert done.returncode == 0, done.stderr[-3000:]
        return done.stdout.strip()

    leg('out')
    if leg('forces') == leg('forces', ATEN_CPU_CAPABILITY='default'):
        pytest.skip("torch's kernels give the same bits here with and "
                    'without SIMD: nothing to detect')
    assert 'MachineChangedWarning' not in leg('back')
    assert 'MachineChangedWarning' in leg('back',
                                          ATEN_CPU_CAPABILITY='default')
