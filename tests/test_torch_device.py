"""TorchCalculator on a torch device: the device argument, refusals before
any step, the weights' digest computed where the weights are, cuBLAS's
workspace rule; and, where CUDA is present, runs out and back on the GPU
and gradients equal to the CPU's.

CI has no GPU: every device path that can run on the CPU runs here with
``device='cpu'``; the CUDA tests skip with the reason.
"""

import pytest

torch = pytest.importorskip('torch', reason='ase_reversible.torch needs '
                            "PyTorch (pip install 'torch==2.13.0')")

import numpy as np  # noqa: E402

from ase_reversible import ReversibleLangevin, ReversibleVerlet  # noqa: E402
from ase_reversible.core.kernels import (CUBLAS_VARIABLE,  # noqa: E402
                                         cublas_problem, prepare_cublas)
from ase_reversible.torch import PairMLP, TorchCalculator  # noqa: E402
from ase_reversible.torch.calculator import device_digest  # noqa: E402

from conftest import DT, argon_bulk  # noqa: E402
from exactness import (assert_runs_back,  # noqa: E402
                       weight_gradients_of_displacement)

CUTOFF = 7.0   # Å
cuda = pytest.mark.skipif(not torch.cuda.is_available(),
                          reason='needs a CUDA device (torch.cuda.is_available()'
                          ' is False here)')


def ar32(calc):
    atoms = argon_bulk((2, 2, 2), 60)
    atoms.rattle(0.05, seed=5)
    atoms.calc = calc
    return atoms


# -- the device argument and its refusals -----------------------------------

def test_the_device_is_the_models_by_default_and_cpu_given_is_the_same():
    model = PairMLP(cutoff=CUTOFF)
    default = TorchCalculator(model, CUTOFF)
    given = TorchCalculator(PairMLP(cutoff=CUTOFF), CUTOFF,
                            device=torch.device('cpu'))
    assert default.device == given.device == torch.device('cpu')
    assert default.forces_are_pure and given.forces_are_pure
    a, b = ar32(default), ar32(given)
    assert np.array_equal(a.get_forces(), b.get_forces())
    assert a.get_potential_energy() == b.get_potential_energy()


@pytest.mark.skipif(torch.cuda.is_available(), reason='CUDA is present')
def test_cuda_without_cuda_is_refused_with_the_remedy():
    with pytest.raises(RuntimeError, match="finds no CUDA device.*device='cpu'"):
        TorchCalculator(PairMLP(cutoff=CUTOFF), CUTOFF, device='cuda')


def test_devices_that_cannot_run_float64_or_are_not_devices_are_refused():
    with pytest.raises(RuntimeError, match='MPS has no float64'):
        TorchCalculator(PairMLP(cutoff=CUTOFF), CUTOFF, device='mps')
    with pytest.raises(ValueError, match='is not a torch device'):
        TorchCalculator(PairMLP(cutoff=CUTOFF), CUTOFF, device='gpu0')


def test_a_model_moved_after_the_calculator_was_made_is_refused():
    model = PairMLP(cutoff=CUTOFF)
    atoms = ar32(TorchCalculator(model, CUTOFF))
    atoms.get_forces()
    model.to('meta')
    atoms.positions[0, 0] += 0.01
    with pytest.raises(RuntimeError, match='is on meta.*model.to'):
        atoms.get_forces()


def test_a_run_leaves_the_callers_deterministic_setting_as_it_was():
    atoms = ar32(TorchCalculator(PairMLP(cutoff=CUTOFF), CUTOFF))
    for setting in (False, True):
        torch.use_deterministic_algorithms(setting)
        try:
            ReversibleVerlet(atoms, DT).run(3)
            assert torch.are_deterministic_algorithms_enabled() is setting
        finally:
            torch.use_deterministic_algorithms(False)


# -- cuBLAS's workspace ----------------------------------------------------------

def test_the_cublas_workspace_is_set_if_unset_and_a_users_value_kept():
    environ = {}
    assert prepare_cublas(environ)
    assert environ[CUBLAS_VARIABLE] == ':4096:8'
    assert cublas_problem('cuda', environ) is None
    mine = {CUBLAS_VARIABLE: ':0:0'}
    assert not prepare_cublas(mine)
    assert mine[CUBLAS_VARIABLE] == ':0:0'
    message = cublas_problem(torch.device('cuda'), mine)
    assert "is ':0:0'" in message and 'export CUBLAS_WORKSPACE_CONFIG' in message
    assert 'is unset' in cublas_problem('cuda', {})
    assert cublas_problem(torch.device('cpu'), {}) is None


# -- the weights' digest on the device --------------------------------------------

def test_the_device_digest_sees_every_change_of_the_weights():
    model = PairMLP(cutoff=CUTOFF)
    tensors = list(model.parameters()) + list(model.buffers())
    first = device_digest(tensors)
    assert device_digest(tensors) == first
    twin = PairMLP(cutoff=CUTOFF)
    assert device_digest(list(twin.parameters()) + list(twin.buffers())) \
        == first
    weight = model.mlp[0].weight
    with torch.no_grad():
        kept = weight[3, 5].item()
        weight[3, 5] = float(np.nextafter(kept, np.inf))     # one ulp
    assert device_digest(tensors) != first
    with torch.no_grad():
        weight[3, 5] = kept
    assert device_digest(tensors) == first
    weight.data[0, 0] += 1e-3                                 # through .data
    assert device_digest(tensors) != first
    weight.data[0, 0] -= 1e-3
    with torch.no_grad():                                     # a swap
        weight[[0, 1]] = weight[[1, 0]].clone()
    assert device_digest(tensors) != first
    with torch.no_grad():
        weight[[0, 1]] = weight[[1, 0]].clone()
    assert device_digest(tensors) == first
    assert device_digest([]) == 'mod:0'


# -- on a GPU ---------------------------------------------------------------------

def big_argon(calc, repeat=8):
    """fcc argon, 4 repeat**3 atoms (2,048 at 8), thermal momenta."""
    atoms = argon_bulk((repeat, repeat, repeat), 60)
    atoms.rattle(0.05, seed=5)
    atoms.calc = calc
    return atoms


@cuda
@pytest.mark.parametrize('dynamics', ['verlet', 'langevin'])
def test_a_model_moved_to_cuda_runs_out_and_back_bit_for_bit(dynamics):
    model = PairMLP(cutoff=CUTOFF).to('cuda')
    calc = TorchCalculator(model, CUTOFF)
    assert calc.device.type == 'cuda' and not calc.forces_are_pure
    atoms = big_argon(calc)
    if dynamics == 'verlet':
        dyn = ReversibleVerlet(atoms, DT)
    else:
        dyn = ReversibleLangevin(atoms, DT, temperature_K=60,
                                 friction=0.01, seed=3)
    assert_runs_back(dyn, 50)


@cuda
def test_parameter_gradients_on_cuda_are_the_cpus_to_1e8():
    grads = {}
    for device in ('cpu', 'cuda'):
        model = PairMLP(cutoff=CUTOFF).to(device)
        calc = TorchCalculator(model, CUTOFF)
        atoms = big_argon(calc, repeat=4)
        g = weight_gradients_of_displacement(ReversibleVerlet(atoms, DT), 100)
        assert all(p.grad.device.type == device for p in model.parameters())
        grads[device] = g.parameters
    for name, cpu in grads['cpu'].items():
        scale = np.abs(cpu).max()
        assert np.abs(grads['cuda'][name] - cpu).max() <= 1e-8 * scale, name


@cuda
def test_the_fingerprint_on_cuda_follows_an_optimiser_step():
    model = PairMLP(cutoff=CUTOFF).to('cuda')
    calc = TorchCalculator(model, CUTOFF)
    before = calc.parameters['weights']
    assert before.startswith('mod:')
    for p in model.parameters():
        p.grad = torch.ones_like(p)
    torch.optim.SGD(model.parameters(), lr=1e-9).step()
    assert calc.parameters['weights'] != before


# -- MACE's own ASE calculator, where mace-torch is installed ------------------

@pytest.mark.parametrize('device', ['cpu', pytest.param('cuda', marks=cuda)])
@pytest.mark.parametrize('dtype', ['float64', 'float32'])
def test_maces_own_calculator_runs_back_under_auto(tmp_path, monkeypatch,
                                                   device, dtype):
    # e3nn 0.4.4 loads its own constants with torch.load, refused by torch
    # >= 2.6's weights-only default; so is MACE's model file.
    monkeypatch.setenv('TORCH_FORCE_NO_WEIGHTS_ONLY_LOAD', '1')
    pytest.importorskip('e3nn', reason='MACE needs e3nn (pip install '
                        'mace-torch==0.3.16 e3nn==0.4.4)')
    calculators = pytest.importorskip(
        'mace.calculators', reason='mace-torch is not installed (pip '
        'install mace-torch==0.3.16 e3nn==0.4.4)')
    from ase.build import bulk

    from ase_reversible.torch.mace import random_mace
    path = tmp_path / 'random.model'
    torch.save(random_mace((29,)), path)
    atoms = bulk('Cu', 'fcc', a=3.6, cubic=True).repeat(2)
    atoms.rattle(0.05, seed=1)
    atoms.calc = calculators.MACECalculator(
        model_paths=str(path), device=device, default_dtype=dtype)
    dyn = ReversibleVerlet(atoms, DT)          # 'auto': no refusal
    assert_runs_back(dyn, 20)


def test_pairs_built_on_the_device_give_the_forces_and_products_bit_for_bit():
    numpy_built = ar32(TorchCalculator(PairMLP(cutoff=CUTOFF), CUTOFF))
    device_built = ar32(TorchCalculator(PairMLP(cutoff=CUTOFF), CUTOFF))
    assert not device_built.calc.device_neighbours   # the CPU's default
    device_built.calc.device_neighbours = True
    device_built.calc.reset()
    v_nc = np.random.default_rng(2).normal(size=(32, 3))
    for atoms in (numpy_built, device_built):
        dyn = ReversibleVerlet(atoms, DT)
        dyn.run(5)
    assert np.array_equal(numpy_built.positions, device_built.positions)
    assert np.array_equal(numpy_built.get_forces(), device_built.get_forces())
    names = numpy_built.calc.differentiable_parameters
    a = numpy_built.calc.vector_jacobian_product(numpy_built, v_nc, names)
    b = device_built.calc.vector_jacobian_product(device_built, v_nc, names)
    assert np.array_equal(a[0], b[0])
    assert all(np.array_equal(a[1][n], b[1][n]) for n in names)
    assert_runs_back(ReversibleVerlet(device_built, DT), 10)


def test_torchscript_optimisation_is_off_once_a_torch_calculator_is_made():
    from ase_reversible.core.kernels import steady_torchscript
    torch._C._set_graph_executor_optimize(True)
    TorchCalculator(PairMLP(cutoff=CUTOFF), CUTOFF)
    assert not torch._C._get_graph_executor_optimize()
    assert not steady_torchscript()      # already off


def test_auto_probes_the_calculator_without_adding_a_torch_hold():
    from ase_reversible.purity import force_provider
    from ase_reversible.purity.introspection import torch_modules
    calc = TorchCalculator(PairMLP(cutoff=CUTOFF), CUTOFF)
    atoms = ar32(calc)
    assert torch_modules(calc) == []
    calc.device_neighbours = True          # as on a GPU: it builds the pairs
    calc.reset()
    # forces_are_pure is the CPU's promise; off it the probe decides.
    provider = force_provider(atoms, 'auto')
    assert provider.mode == 'trust' and provider.holds == ()
