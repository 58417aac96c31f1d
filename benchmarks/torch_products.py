"""PyTorch models: the vector-Jacobian product against a force call, and
the canonical neighbour list against ASE's (needs PyTorch; the method is
docs/benchmarks.md's)."""

from __future__ import annotations

import common  # noqa: F401  (first: pins BLAS threads before numpy)

import os
import statistics
import time

import numpy as np

SIZES = {64: (2, 2, 4), 512: (4, 4, 8), 2048: (8, 8, 8)}
MODELS = ('pair MLP', 'Lennard-Jones')
MLP_CUTOFF = 7.0   # Å


def _system(n_atoms):
    from ase.build import bulk
    atoms = bulk('Ar', 'fcc', a=5.26, cubic=True).repeat(SIZES[n_atoms])
    atoms.rattle(0.1, seed=1)
    return atoms


def _calculator(model, threads):
    from ase_reversible.app.systems import AR_EPSILON, AR_SIGMA
    from ase_reversible.torch import LennardJones, PairMLP, TorchCalculator
    if model == 'pair MLP':
        return TorchCalculator(PairMLP(cutoff=MLP_CUTOFF), MLP_CUTOFF,
                               threads=threads)
    lj = LennardJones(AR_EPSILON, AR_SIGMA)
    return TorchCalculator(lj, lj.rc, threads=threads)


def _timed(function):
    cpu, wall = time.process_time(), time.perf_counter()
    function()
    return time.process_time() - cpu, time.perf_counter() - wall


def measure(model, n_atoms, threads, rounds):
    from ase.neighborlist import neighbor_list
    from ase_reversible.torch import neighbour_list
    from ase_reversible.torch.neighbours import NeighbourList
    atoms = _system(n_atoms)
    calc = _calculator(model, threads)
    atoms.calc = calc
    names = calc.differentiable_parameters
    v_nc = np.random.default_rng(0).normal(size=(n_atoms, 3))
    cutoff = calc.parameters['cutoff']
    x0_nc = atoms.get_positions()
    atoms.get_forces()
    calc.vector_jacobian_product(atoms, v_nc, names)   # keeps graphs now
    listing = NeighbourList(cutoff, skin=1.0)
    listing(atoms.positions, atoms.cell.array, atoms.pbc)
    times = {k: [] for k in ('force', 'product', 'product_fresh',
                             'neighbours', 'neighbours_skin',
                             'ase_neighbours')}
    for r in range(rounds):
        atoms.positions = x0_nc
        atoms.positions[0, 0] += 1e-9 * (r + 1)
        times['force'].append(_timed(atoms.get_forces))
        times['product'].append(_timed(
            lambda: calc.vector_jacobian_product(atoms, v_nc, names)))
        times['product_fresh'].append(_timed(
            lambda: calc.vector_jacobian_product(atoms, v_nc, names)))
        if threads == 1:
            times['neighbours'].append(_timed(lambda: neighbour_list(
                atoms.positions, atoms.cell.array, atoms.pbc, cutoff)))
            times['neighbours_skin'].append(_timed(lambda: listing(
                atoms.positions, atoms.cell.array, atoms.pbc)))
            times['ase_neighbours'].append(_timed(
                lambda: neighbor_list('ijS', atoms, cutoff)))
    out = {'model': model, 'n_atoms': n_atoms, 'threads': threads,
           'n_parameters': sum(p.numel() for p in calc.model.parameters()),
           'cutoff': cutoff, 'rounds': rounds,
           'n_edges': int(neighbour_list(atoms.positions, atoms.cell.array,
                                         atoms.pbc, cutoff)[0].shape[1])}
    for key, values in times.items():
        if not values:
            continue
        out[f'{key}_cpu'] = statistics.median(v[0] for v in values)
        out[f'{key}_wall'] = statistics.median(v[1] for v in values)
    for key in ('product', 'product_fresh'):
        out[f'{key}_ratio_cpu'] = statistics.median(
            p[0] / f[0] for p, f in zip(times[key], times['force']))
        out[f'{key}_ratio_wall'] = statistics.median(
            p[1] / f[1] for p, f in zip(times[key], times['force']))
    if times['neighbours']:
        out['ase_over_ours_cpu'] = statistics.median(
            a[0] / o[0] for a, o in zip(times['ase_neighbours'],
                                        times['neighbours']))
    return out


def run(quick):
    try:
        import torch
    except ImportError:
        return {'skipped': "PyTorch is not installed (pip install "
                           "'torch==2.13.0')"}
    sizes = (64,) if quick else tuple(SIZES)
    threads = (1,) if quick else (1, 2)
    rounds = 2 if quick else 7
    load_start = os.getloadavg()[0]
    cases = []
    for n_atoms in sizes:
        for model in MODELS:
            for t in threads:
                case = measure(model, n_atoms, t, rounds)
                print(f"  {model}, {n_atoms} atoms, {t} thread(s): product "
                      f"{case['product_ratio_cpu']:.2f}x a force call",
                      flush=True)
                cases.append(case)
    return {'torch': torch.__version__, 'cases': cases,
            'load_average': [load_start, os.getloadavg()[0]]}

