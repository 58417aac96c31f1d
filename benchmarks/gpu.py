"""PyTorch models on a GPU: reversible against ASE's VelocityVerlet per
step, the product and the neighbour list against a force call,
deterministic against default kernels, memory of long retraces, and
MACE's own calculator under 'auto' where mace-torch is installed.

Runs on the first CUDA device torch finds, else on the CPU with
``device='cpu'`` (labelled so: the same paths, CPU timings).  Everything
is interleaved (the contestants' order rotated each round) and reported as
medians; a GPU's times are wall times after ``torch.cuda.synchronize``,
which every force call reaches anyway (the forces come back to the host).
Once the reversible integrator has taken a torch calculator on,
TorchScript's profiling-guided optimisation is off for the process
(``ase_reversible.core.kernels.steady_torchscript``), so VelocityVerlet
runs without it too: MACE's ratio compares the two under the same
setting, not against VelocityVerlet as it runs alone (on this CPU MACE
was faster without the optimisation: 48 against 88 ms per call).
"""

from __future__ import annotations

import common  # noqa: F401  (first: pins BLAS threads before numpy)

import statistics
import tempfile
import time

import numpy as np
from harness import Contestant, max_rss_bytes, per_step, time_interleaved

#: Atoms -> fcc repeats of the 4-atom cubic argon cell.
SIZES = {256: 4, 2048: 8, 32000: 20}
CUTOFF = 8.0           # Å, argon's PairMLP
TIMESTEP_FS = 5.0
TEMPERATURE_K = 60.0


def _device():
    import torch
    return torch.device('cuda' if torch.cuda.is_available() else 'cpu')


def _sync(device):
    import torch
    if device.type == 'cuda':
        torch.cuda.synchronize()


def _argon(n_atoms, seed=1):
    from ase.build import bulk

    from ase_reversible.app.systems import thermalize
    r = SIZES[n_atoms]
    atoms = bulk('Ar', 'fcc', a=5.26, cubic=True).repeat((r, r, r))
    atoms.rattle(0.05, seed=seed)
    return thermalize(atoms, TEMPERATURE_K, seed=seed)


def _calculator(device):
    from ase_reversible.torch import PairMLP, TorchCalculator
    return TorchCalculator(PairMLP(cutoff=CUTOFF).to(device), CUTOFF)


def _timed(function, device):
    _sync(device)
    t0 = time.perf_counter()
    function()
    _sync(device)
    return time.perf_counter() - t0


def step_ratio(n_atoms, device, steps, rounds):
    """Seconds per step, ReversibleVerlet against VelocityVerlet, each with
    its own calculator on ``device``."""
    from ase import units
    from ase.md.verlet import VelocityVerlet

    from ase_reversible import ReversibleVerlet
    dt = TIMESTEP_FS * units.fs
    runners = {}
    for name, make in (('reversible', ReversibleVerlet),
                       ('velocity_verlet', VelocityVerlet)):
        atoms = _argon(n_atoms)
        atoms.calc = _calculator(device)
        runners[name] = make(atoms, dt)
        runners[name].run(2)
    contestants = [Contestant(k, v) for k, v in runners.items()]
    wall, cpu = time_interleaved(contestants, steps, rounds)
    out = {'n_atoms': n_atoms, 'steps_per_block': steps, 'rounds': rounds,
           **per_step(wall, cpu)}
    out['ratio'] = statistics.median(
        r / v for r, v in zip(wall['reversible'], wall['velocity_verlet']))
    provider = runners['reversible'].force_purity
    out['force_purity'] = provider.mode
    out['spot_checks'] = getattr(provider.spot_check, 'checks', None)
    return out


def call_ratios(n_atoms, device, rounds):
    """Medians over interleaved rounds: a force call, the product with
    every parameter, the device neighbour list (a skin hit and a fresh
    build), and the bare model's forces under deterministic and default
    kernels."""
    import torch

    from ase_reversible.core.kernels import deterministic_kernels
    from ase_reversible.torch import TorchNeighbourList
    atoms = _argon(n_atoms)
    calc = _calculator(device)
    atoms.calc = calc
    names = calc.differentiable_parameters
    v_nc = np.random.default_rng(0).normal(size=(n_atoms, 3))
    x0_nc = atoms.get_positions()
    cell, pbc = atoms.cell.array, atoms.pbc
    listing = TorchNeighbourList(CUTOFF, skin=1.0, device=device)
    x = torch.tensor(x0_nc, device=device)
    edge_index, edge_shift = listing(x, cell, pbc)[:2]
    numbers = torch.tensor(atoms.numbers, device=device)
    cell_t = torch.tensor(cell, device=device)

    def bare_forces():
        xg = x.clone().requires_grad_(True)
        energy = calc.model(xg, numbers, cell_t, edge_index, edge_shift)
        torch.autograd.grad(energy, xg)

    def held(deterministic):
        def call():
            if deterministic:
                with deterministic_kernels():
                    bare_forces()
            else:
                bare_forces()
        return call

    atoms.get_forces()
    calc.vector_jacobian_product(atoms, v_nc, names)   # keeps graphs now
    cases = {
        'force': lambda: atoms.get_forces(),
        'product': lambda: calc.vector_jacobian_product(atoms, v_nc, names),
        'list_skin_hit': lambda: listing(x, cell, pbc),
        'list_fresh': lambda: TorchNeighbourList(
            CUTOFF, skin=1.0, device=device)(x, cell, pbc),
        'kernels_deterministic': held(True),
        'kernels_default': held(False),
    }
    times = {k: [] for k in cases}
    keys = list(cases)
    for r in range(rounds):
        atoms.positions = x0_nc
        atoms.positions[0, 0] += 1e-9 * (r + 1)
        for key in keys[r % len(keys):] + keys[:r % len(keys)]:
            if key == 'product':
                atoms.get_forces()   # the adjoint asks right after them
            times[key].append(_timed(cases[key], device))
    out = {'n_atoms': n_atoms, 'rounds': rounds,
           'n_edges': int(edge_index.shape[1]),
           'n_parameters': sum(p.numel() for p in calc.model.parameters()),
           'seconds': {k: statistics.median(v) for k, v in times.items()}}
    force = times['force']
    out['over_force'] = {
        k: statistics.median(a / f for a, f in zip(times[k], force))
        for k in ('product', 'list_skin_hit', 'list_fresh')}
    out['deterministic_over_default'] = statistics.median(
        d / f for d, f in zip(times['kernels_deterministic'],
                              times['kernels_default']))
    return out


def retrace_memory(device, steps_list, n_atoms=256):
    """Peak memory of one run of ``steps`` and its retrace with every
    parameter's gradient, for each entry of ``steps_list`` (ascending): on
    CUDA the allocator's peak, on the CPU the process's peak resident set
    (which only grows, so a flat retrace shows as no growth)."""
    import torch
    from ase import units

    from ase_reversible import ReversibleVerlet
    points = []
    for steps in steps_list:
        atoms = _argon(n_atoms)
        calc = _calculator(device)
        atoms.calc = calc
        dyn = ReversibleVerlet(atoms, TIMESTEP_FS * units.fs)
        if device.type == 'cuda':
            torch.cuda.synchronize()
            torch.cuda.reset_peak_memory_stats()
        before = max_rss_bytes()
        t0 = time.perf_counter()
        x0_nc = atoms.get_positions()
        dyn.run(steps)
        dyn.backpropagate(steps, atoms.get_positions() - x0_nc,
                          parameters=calc.differentiable_parameters)
        point = {'steps': steps, 'seconds': time.perf_counter() - t0,
                 'max_rss_before_bytes': before,
                 'max_rss_bytes': max_rss_bytes()}
        if device.type == 'cuda':
            point['cuda_peak_bytes'] = torch.cuda.max_memory_allocated()
        points.append(point)
    return {'n_atoms': n_atoms, 'points': points}


def mace_case(device, dtype, n_atoms, steps, rounds, folder):
    """MACE's own ASE calculator (``random_mace``, copper) on ``device`` in
    ``dtype`` under force_purity='auto': the handling chosen, whether
    ``steps`` out and back land bit for bit, and its time per step against
    VelocityVerlet (interleaved); or why it was not measured."""
    import os
    os.environ.setdefault('TORCH_FORCE_NO_WEIGHTS_ONLY_LOAD', '1')
    try:
        import torch
        from mace.calculators import MACECalculator

        from ase_reversible.torch.mace import random_mace
    except ImportError as error:
        return {'dtype': dtype, 'skipped': f'mace-torch is not installed '
                f'({error})'}
    from ase import units
    from ase.build import bulk
    from ase.md.verlet import VelocityVerlet

    from ase_reversible import ReversibleVerlet
    path = os.path.join(folder, 'random_mace.model')
    if not os.path.exists(path):
        torch.save(random_mace((29,)), path)
    repeat = round((n_atoms / 4) ** (1 / 3))
    runners = {}
    for name, make in (('reversible', ReversibleVerlet),
                       ('velocity_verlet', VelocityVerlet)):
        atoms = bulk('Cu', 'fcc', a=3.6, cubic=True).repeat(repeat)
        atoms.rattle(0.05, seed=1)
        atoms.calc = MACECalculator(model_paths=path, device=str(device),
                                    default_dtype=dtype)
        runners[name] = make(atoms, 2 * units.fs)
    dyn = runners['reversible']
    atoms = dyn.atoms
    x0_nc, p0_nc = atoms.get_positions(), atoms.get_momenta()
    dyn.run(steps)
    dyn.reverse()
    dyn.run(steps)
    exact = bool(np.array_equal(atoms.positions, x0_nc)
                 and np.array_equal(atoms.get_momenta(), p0_nc))
    dyn.reverse()
    runners['velocity_verlet'].run(2)
    wall, cpu = time_interleaved(
        [Contestant(k, v) for k, v in runners.items()], 2, rounds)
    provider = dyn.force_purity
    return {'dtype': dtype, 'n_atoms': len(atoms), 'steps': steps,
            'force_purity': provider.todict(),
            'holds': [type(context).__name__ for context, _ in provider.holds],
            'clean_recomputations': getattr(provider,
                                            'clean_recomputations', None),
            'exact': exact, **per_step(wall, cpu),
            'ratio': statistics.median(
                r / v for r, v in zip(wall['reversible'],
                                      wall['velocity_verlet']))}


def run(quick):
    try:
        import torch
    except ImportError:
        return {'skipped': "PyTorch is not installed (pip install "
                           "'torch==2.13.0')"}
    device = _device()
    on_gpu = device.type == 'cuda'
    sizes = (256,) if quick else ((2048, 32000) if on_gpu else (2048,))
    rounds = 3 if quick else 9
    steps = 2 if quick else 10
    memory_steps = (20, 50) if quick else ((1000, 10000) if on_gpu
                                           else (100, 1000))
    out = {'torch': torch.__version__, 'device': str(device),
           'device_name': (torch.cuda.get_device_name(device) if on_gpu
                           else 'CPU (no CUDA device found)'),
           'per_step': [], 'calls': []}
    for n_atoms in sizes:
        case = step_ratio(n_atoms, device, steps, rounds)
        print(f"  {n_atoms} atoms: reversible / VelocityVerlet per step "
              f"{case['ratio']:.3f}", flush=True)
        out['per_step'].append(case)
        calls = call_ratios(n_atoms, device, rounds)
        print(f"  {n_atoms} atoms: product {calls['over_force']['product']:.2f}"
              f"x a force call, list {calls['over_force']['list_skin_hit']:.3f}"
              f"x, deterministic kernels "
              f"{calls['deterministic_over_default']:.3f}x", flush=True)
        out['calls'].append(calls)
    out['memory'] = retrace_memory(device, memory_steps)
    with tempfile.TemporaryDirectory() as folder:
        out['mace'] = [mace_case(device, dtype, 108 if quick or not on_gpu
                                 else 2048, 10 if quick else 200, rounds,
                                 folder)
                       for dtype in ('float64', 'float32')]
    return out
