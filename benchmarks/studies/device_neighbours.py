"""The canonical neighbour list built by torch on a device against the numpy
one: a fresh build and a call on a skin hit, rattled fcc argon (a = 5.26
Å), 8 Å cut-off, 1 Å skin, medians of interleaved repetitions, one torch
thread.  Each torch result is checked equal, bit for bit, to numpy's.

    python benchmarks/studies/device_neighbours.py --device cuda
    python benchmarks/run_all.py --only device_neighbours

The second stores its results in the gpu section (on the first CUDA
device torch finds, else on the CPU).
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(1, str(Path(__file__).resolve().parent.parent))

import common  # noqa: E402,F401  (first: pins BLAS threads before numpy)

import argparse  # noqa: E402
import statistics  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402

CUTOFF, SKIN, LATTICE = 8.0, 1.0, 5.26
REPEATS = {False: (8, 20), True: (8,)}     # 2,048 and 32,000 atoms


def measure(repeat, device, rounds):
    """Median seconds of each way of listing, and the list's sizes."""
    import torch
    from ase.build import bulk

    from ase_reversible.torch import TorchNeighbourList
    from ase_reversible.torch.neighbours import NeighbourList, neighbour_list
    torch.set_num_threads(1)

    def synchronize():
        if torch.device(device).type == 'cuda':
            torch.cuda.synchronize()

    def timed(function):
        synchronize()
        tic = time.perf_counter()
        result = function()
        synchronize()
        return time.perf_counter() - tic, result

    atoms = bulk('Ar', 'fcc', a=LATTICE, cubic=True).repeat(repeat)
    atoms.rattle(0.05, seed=1)
    x0_nc, cell, pbc = atoms.positions.copy(), atoms.cell.array, atoms.pbc
    kept_numpy = NeighbourList(CUTOFF, SKIN)
    kept_torch = TorchNeighbourList(CUTOFF, SKIN, device)
    kept_numpy(x0_nc, cell, pbc)
    kept_torch(x0_nc, cell, pbc)
    times = {name: [] for name in (
        'numpy_fresh', 'numpy_fresh_with_skin', 'torch_fresh_with_skin',
        'numpy_skin_hit', 'torch_skin_hit')}
    rng = np.random.default_rng(0)
    for _ in range(rounds):
        x_nc = x0_nc + rng.normal(0.0, 0.01, x0_nc.shape)
        x = torch.tensor(x_nc, device=device)
        for name, function in [
                ('numpy_fresh',
                 lambda: neighbour_list(x_nc, cell, pbc, CUTOFF)),
                ('numpy_fresh_with_skin',
                 lambda: NeighbourList(CUTOFF, SKIN)(x_nc, cell, pbc)),
                ('torch_fresh_with_skin',
                 lambda: TorchNeighbourList(CUTOFF, SKIN, device)(
                     x, cell, pbc)),
                ('numpy_skin_hit', lambda: kept_numpy(x_nc, cell, pbc)),
                ('torch_skin_hit', lambda: kept_torch(x, cell, pbc))]:
            seconds, result = timed(function)
            times[name].append(seconds)
            if name == 'numpy_fresh':
                expected = result
            elif name.startswith('torch'):
                assert all(np.array_equal(a.cpu().numpy(), b)
                           for a, b in zip(result, expected))
    return {'n_atoms': len(atoms), 'device': str(device),
            'n_pairs': int(expected[0].shape[1]),
            'n_candidates': int(kept_torch._search.s_pc.shape[0]),
            'rounds': rounds,
            'median_seconds': {name: statistics.median(values)
                               for name, values in times.items()}}


def run(quick, device=None, rounds=5):
    """The records of each size, on ``device`` (default: the first CUDA
    device, else the CPU)."""
    import torch
    if device is None:
        device = 'cuda' if torch.cuda.is_available() else 'cpu'
    return {'cases': [measure(repeat, device, rounds)
                      for repeat in REPEATS[quick]]}


if __name__ == '__main__':
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--device', default='cpu')
    parser.add_argument('--rounds', type=int, default=5)
    parser.add_argument('--quick', action='store_true')
    arguments = parser.parse_args()
    for record in run(arguments.quick, arguments.device,
                      arguments.rounds)['cases']:
        print(f"{record['n_atoms']} atoms on {record['device']}: "
              f"{record['n_pairs']} pairs, {record['n_candidates']} "
              'candidates kept')
        for name, seconds in record['median_seconds'].items():
            print(f'  {name:24s} {1e3 * seconds:10.2f} ms')
