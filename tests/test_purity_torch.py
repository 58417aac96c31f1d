"""force_purity='auto' on third-party calculators that hold torch models:
deterministic kernels where the plain ones vary from call to call, and
refusals that name run-to-run nondeterminism."""

import subprocess
import sys
import warnings

import numpy as np
import pytest
from ase.calculators.calculator import Calculator, all_changes
from ase.calculators.lj import LennardJones
from ase.calculators.mixing import SumCalculator

from ase_reversible import (ImpureForcesError, ReversibleVerlet,
                            check_calculator)
from ase_reversible.purity import (DEFAULT_FORCE_NOISE, SPOT_CHECK_INTERVAL,
                                   GuardedForces, TrustedForces)
from ase_reversible.purity.deterministic import DeterministicKernels
from ase_reversible.purity.introspection import torch_modules

from conftest import AR_EPSILON, AR_RC, AR_SIGMA, DT, argon_cluster
from exactness import assert_runs_back, run_until_refused

torch = pytest.importorskip('torch', reason='the torch hold is for '
                            "calculators holding PyTorch models (pip install "
                            "'torch==2.13.0')")


class ShuffledPairSum(torch.nn.Module):
    """Lennard-Jones forces ``[n_atoms, 3]`` (eV/Å) and energy (eV) of all
    pairs, added onto the atoms by ``index_add_`` over the pairs in an order
    drawn anew at every call (``torch.randperm`` without a fixed
    generator) unless ``torch.are_deterministic_algorithms_enabled()``.

    This emulates, on the CPU, whose kernels are deterministic, CUDA's
    atomic adds: their order changes from call to call, so the forces at
    the same positions differ in the last bits, and PyTorch's deterministic
    mode fixes it.  ``always_shuffled``: the order is drawn even then, as
    in a model with an operation that has no deterministic kernel.
    """

    def __init__(self, dtype, always_shuffled=False):
        super().__init__()
        self.register_buffer('epsilon', torch.tensor(AR_EPSILON, dtype=dtype))
        self.register_buffer('sigma', torch.tensor(AR_SIGMA, dtype=dtype))
        self.always_shuffled = always_shuffled

    def forward(self, x_nc, i_p, j_p):
        if self.always_shuffled or not (
                torch.are_deterministic_algorithms_enabled()):
            order_p = torch.randperm(len(i_p), device=i_p.device)
            i_p, j_p = i_p[order_p], j_p[order_p]
        r_pc = x_nc[j_p] - x_nc[i_p]
        r2_p = (r_pc * r_pc).sum(dim=1)
        s6_p = (self.sigma**2 / r2_p)**3
        e = (4 * self.epsilon * (s6_p * s6_p - s6_p)).sum()
        # The force on j of the pair (i, j); on i the opposite.
        g_p = 24 * self.epsilon * (2 * s6_p * s6_p - s6_p) / r2_p
        f_pc = g_p[:, None] * r_pc
        f_nc = torch.zeros_like(x_nc)
        f_nc.index_add_(0, j_p, f_pc)
        f_nc.index_add_(0, i_p, -f_pc)
        return e, f_nc


class TorchPairCalculator(Calculator):
    """An ASE calculator holding its torch model in ``.models``, a list, as
    MACE's ``MACECalculator`` does; it does not declare its forces pure.
    ``device``: where the model runs (the forces come back as float64
    numpy).

    ``deterministic_calls`` records, for every calculation, whether
    PyTorch's deterministic algorithms were enabled during it.
    """

    implemented_properties = ['energy', 'forces']

    def __init__(self, dtype=torch.float64, always_shuffled=False,
                 device='cpu'):
        super().__init__()
        self.models = [ShuffledPairSum(dtype, always_shuffled).to(device)]
        self.deterministic_calls = []

    def calculate(self, atoms=None, properties=('energy',),
                  system_changes=all_changes):
        super().calculate(atoms, properties, system_changes)
        model = self.models[0]
        device = model.sigma.device
        n = len(self.atoms)
        i_p, j_p = np.triu_indices(n, k=1)
        x_nc = torch.tensor(self.atoms.positions, dtype=model.sigma.dtype,
                            device=device)
        self.deterministic_calls.append(
            torch.are_deterministic_algorithms_enabled())
        with torch.no_grad():
            e, f_nc = model(x_nc, torch.tensor(i_p, device=device),
                            torch.tensor(j_p, device=device))
        self.results = {
            'energy': float(e.cpu()),
            'forces': f_nc.cpu().numpy().astype(np.float64)}


CUDA = pytest.mark.skipif(
    not torch.cuda.is_available(),
    reason='needs a CUDA GPU: deterministic kernels on CUDA (atomic adds, '
           "cuBLAS's workspace)")


def held_calls(provider):
    """``{kind of hold: the provider's calls it is held around}``."""
    return {type(context).__name__: calls
            for context, calls in provider.holds}


@pytest.fixture
def user_setting():
    """Restores the process's deterministic setting after a test that
    changes it."""
    enabled = torch.are_deterministic_algorithms_enabled()
    warn_only = torch.is_deterministic_algorithms_warn_only_enabled()
    yield
    torch.use_deterministic_algorithms(enabled, warn_only=warn_only)


def cluster(calc):
    atoms = argon_cluster(3, 60)
    atoms.calc = calc
    return atoms


def run_to_run_refusal(calc):
    """The message with which 'auto' refuses ``calc`` on an argon cluster,
    checked to name run-to-run nondeterminism and not history."""
    with pytest.raises(ImpureForcesError) as refused:
        ReversibleVerlet(cluster(calc), DT)
    message = str(refused.value)
    assert 'run-to-run nondeterminism' in message
    assert 'history' not in message
    return message


def test_torch_modules_are_found_in_attributes_lists_dicts_and_members():
    calc = TorchPairCalculator()
    inner = calc.models[0]
    assert torch_modules(calc) == [inner]
    calc.model = inner  # the same module twice: listed once
    calc.heads = {'energy': torch.nn.Linear(1, 1)}
    assert torch_modules(calc) == [inner, calc.heads['energy']]
    lj = LennardJones()
    assert torch_modules(SumCalculator([lj, calc]))[0] is inner
    assert torch_modules(lj) == []


def test_looking_for_torch_modules_does_not_import_torch():
    code = ('import sys\n'
            'from ase.calculators.lj import LennardJones\n'
            'from ase_reversible.purity.introspection import torch_modules\n'
            'assert torch_modules(LennardJones()) == []\n'
            "assert 'torch' not in sys.modules\n")
    done = subprocess.run([sys.executable, '-c', code], capture_output=True,
                          text=True, timeout=120)
    assert done.returncode == 0, done.stderr


def test_float64_noise_is_guarded_with_clean_recomputations_on_held_kernels():
    atoms = cluster(TorchPairCalculator(torch.float64))
    # A grid fine for the bound, so that kicks are flagged often.
    dyn = ReversibleVerlet(atoms, DT, momentum_quantum=2.0**-44)
    guard = dyn.force_purity
    assert isinstance(guard, GuardedForces)
    assert guard.force_noise <= DEFAULT_FORCE_NOISE
    kernels = guard.held(DeterministicKernels)
    assert held_calls(guard) == {'DeterministicKernels': ('clean_forces',)}
    entered = kernels.entries
    calls = atoms.calc.deterministic_calls
    calls.clear()
    assert_runs_back(dyn, 100)
    assert guard.clean_recomputations > 0
    # Each clean recomputation calls the model twice (away and back), both
    # under deterministic kernels; every other call runs as the user set.
    assert kernels.entries - entered == guard.clean_recomputations
    assert sum(calls) == 2 * guard.clean_recomputations
    assert not torch.are_deterministic_algorithms_enabled()


def test_float32_noise_is_trusted_with_every_call_on_held_kernels():
    atoms = cluster(TorchPairCalculator(torch.float32))
    dyn = ReversibleVerlet(atoms, DT)
    held = dyn.force_purity
    assert type(held) is TrustedForces
    assert held_calls(held) == {'DeterministicKernels': ('forces',)}
    calls = atoms.calc.deterministic_calls
    calls.clear()
    assert_runs_back(dyn, 100)
    assert calls and all(calls)
    assert not torch.are_deterministic_algorithms_enabled()


@pytest.mark.parametrize('dtype', [torch.float64, torch.float32],
                         ids=['float64', 'float32'])
def test_a_model_random_under_deterministic_kernels_is_refused_as_such(
        dtype):
    message = run_to_run_refusal(
        TorchPairCalculator(dtype, always_shuffled=True))
    assert "deterministic kernels" in message and 'float64' in message
    # Guarded rounding is offered where it can absorb the noise.
    assert ("force_purity='guarded'" in message) == (dtype == torch.float64)
    assert not torch.are_deterministic_algorithms_enabled()


@pytest.mark.parametrize('enabled', [False, True], ids=['off', 'on'])
@pytest.mark.parametrize('dtype', [torch.float64, torch.float32],
                         ids=['float64', 'float32'])
def test_the_users_deterministic_setting_is_restored_after_every_call(
        user_setting, enabled, dtype):
    torch.use_deterministic_algorithms(enabled)
    atoms = cluster(TorchPairCalculator(dtype))
    dyn = ReversibleVerlet(atoms, DT, momentum_quantum=2.0**-44)
    assert torch.are_deterministic_algorithms_enabled() == enabled
    if enabled and dtype == torch.float64:
        # Pure as the user runs it: nothing to hold.
        assert held_calls(dyn.force_purity) == {}
    if dtype == torch.float32:
        # Held whatever a probe sees: float32 noise comes and goes.
        assert held_calls(dyn.force_purity) == {
            'DeterministicKernels': ('forces',)}
    assert_runs_back(dyn, 20)
    assert torch.are_deterministic_algorithms_enabled() == enabled
    assert not torch.is_deterministic_algorithms_warn_only_enabled()


def test_a_torch_model_made_nondeterministic_in_a_run_is_stopped(
        user_setting):
    torch.use_deterministic_algorithms(True)
    atoms = cluster(TorchPairCalculator(torch.float64))
    dyn = ReversibleVerlet(atoms, DT)
    assert held_calls(dyn.force_purity) == {}  # pure as it was probed
    torch.use_deterministic_algorithms(False)
    _, steps = run_until_refused(
        dyn, 2 * SPOT_CHECK_INTERVAL, ImpureForcesError,
        r'torch.use_deterministic_algorithms\(True\)')
    assert 0 < steps < 2 * SPOT_CHECK_INTERVAL


class CallNoiseLJ(LennardJones):
    """ASE's LennardJones whose forces carry fresh random noise of about
    1e-15 eV/Å at every call, as parallel sums in a varying order do."""

    def calculate(self, atoms=None, properties=('energy',),
                  system_changes=all_changes):
        super().calculate(atoms, properties, system_changes)
        f_nc = self.results['forces']
        self.results['forces'] = f_nc + np.random.default_rng().normal(
            0.0, 1e-15, f_nc.shape)


def test_noise_between_repeated_calls_is_refused_as_run_to_run():
    message = run_to_run_refusal(
        CallNoiseLJ(sigma=AR_SIGMA, epsilon=AR_EPSILON, rc=AR_RC))
    assert 'one thread' in message and "force_purity='guarded'" in message


def test_pytorchs_warning_for_an_op_without_a_deterministic_kernel_once():
    # put_ has no deterministic kernel on the CPU: PyTorch warns at every
    # call under warn_only, and a run would repeat it at every step.
    kernels = DeterministicKernels()
    x = torch.zeros(3)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter('always')
        for _ in range(3):
            with kernels():
                x.put_(torch.tensor([0]), torch.tensor([1.0]))
    shown = [w for w in caught
             if 'does not have a deterministic implementation' in
             str(w.message)]
    assert len(shown) == 1 and kernels.entries == 3
    assert not torch.are_deterministic_algorithms_enabled()


def test_a_torch_model_mixed_with_ase_lists_is_sorted_and_held():
    lj = LennardJones(sigma=AR_SIGMA, epsilon=AR_EPSILON, rc=AR_RC)
    model = TorchPairCalculator(torch.float64)
    atoms = cluster(SumCalculator([lj, model]))
    dyn = ReversibleVerlet(atoms, DT)
    provider = dyn.force_purity
    assert provider.mode == 'sorted'
    assert held_calls(provider) == {'DeterministicKernels': ('forces',)}
    model.deterministic_calls.clear()
    assert_runs_back(dyn, 50)
    assert all(model.deterministic_calls)


@pytest.mark.parametrize('dtype, words', [
    (torch.float64, 'The clean recomputations run under'),
    (torch.float32, 'Every force call runs under')],
    ids=['float64', 'float32'])
def test_check_calculator_names_the_kernel_hold_in_its_cost(dtype, words):
    verdict = check_calculator(cluster(TorchPairCalculator(dtype)))
    assert verdict.exact
    assert words in verdict.cost and 'deterministic kernels' in verdict.cost


@CUDA
@pytest.mark.parametrize('dtype, provider', [
    (torch.float64, GuardedForces), (torch.float32, TrustedForces)],
    ids=['float64', 'float32'])
def test_on_cuda_the_kernel_hold_runs_back_bit_for_bit(dtype, provider):
    atoms = cluster(TorchPairCalculator(dtype, device='cuda'))
    dyn = ReversibleVerlet(atoms, DT)
    assert type(dyn.force_purity) is provider
    assert dyn.force_purity.held(DeterministicKernels) is not None
    assert_runs_back(dyn, 100)


@CUDA
def test_on_cuda_a_cublas_workspace_the_kernels_cannot_use_is_refused(
        monkeypatch):
    monkeypatch.setenv('CUBLAS_WORKSPACE_CONFIG', ':0:0')
    with pytest.raises(ImpureForcesError, match='CUBLAS_WORKSPACE_CONFIG'):
        ReversibleVerlet(cluster(TorchPairCalculator(device='cuda')), DT)



def test_torchscript_optimisation_is_turned_off_for_a_torch_calculator():
    # A scripted model's bits change once TorchScript has optimised it,
    # after calls made by anyone (core/kernels.py has the measurements).
    torch._C._set_graph_executor_optimize(True)
    ReversibleVerlet(cluster(TorchPairCalculator(torch.float64)), DT)
    assert not torch._C._get_graph_executor_optimize()
