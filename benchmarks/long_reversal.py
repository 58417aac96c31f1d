"""Long exact-reversal runs with ASE's pure-Python LennardJones.

The test suite runs the 20,000-step hot Ar147 round trip with asap3; with
ASE's LennardJones it takes minutes per scheme, so it lives here.

    python benchmarks/long_reversal.py [--steps 20000] [velocity] [position]
"""

import argparse
import time

import numpy as np
from ase import units

from ase_reversible import ReversibleVerlet
from ase_reversible.demo import make_cluster


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument('schemes', nargs='*', default=['velocity', 'position'])
    parser.add_argument('--steps', type=int, default=20000)
    args = parser.parse_args()
    for scheme in args.schemes:
        atoms = make_cluster(147, 120.0, seed=0)
        dyn = ReversibleVerlet(atoms, 5 * units.fs, scheme=scheme)
        x0, p0 = atoms.get_positions(), atoms.get_momenta()
        tic = time.perf_counter()
        dyn.run(args.steps)
        furthest = np.abs(atoms.positions - x0).max()
        dyn.reverse()
        dyn.run(args.steps)
        exact = (np.array_equal(atoms.positions, x0)
                 and np.array_equal(atoms.get_momenta(), p0))
        print(f'Ar147 120 K, ASE LennardJones, {scheme}, {args.steps} steps '
              f'each way: exact={exact}, largest displacement at the turn '
              f'{furthest:.2f} Å, {time.perf_counter() - tic:.0f} s',
              flush=True)


if __name__ == '__main__':
    main()
