"""Force history noise of each calculator, and what a rebuild costs.

For periodic systems of about 500 atoms with atoms on the cell faces:
forces computed by a fresh calculator against forces at the same positions
from a calculator whose neighbour list was built elsewhere (0.25 Å away,
then 0.05 Å away), over several trials; and the median time of a normal
force call against one that first forces a neighbour-list rebuild (fresh
calculator), measured interleaved.  Prints a Markdown table.

    python benchmarks/force_noise.py
"""

import time

import numpy as np
from ase.build import bulk
from ase.calculators.emt import EMT
from ase.calculators.lj import LennardJones

import asap3

SYSTEMS = {
    'Cu500 periodic': lambda: bulk('Cu', cubic=True) * (5, 5, 5),
    'Ar500 periodic': lambda: bulk('Ar', 'fcc', a=5.26, cubic=True) * (5, 5, 5),
}
CALCULATORS = [
    ('ASE EMT', 'Cu500 periodic', EMT),
    ('ASE LennardJones', 'Ar500 periodic',
     lambda: LennardJones(sigma=3.4, epsilon=0.0104, rc=8.5)),
    ('asap3 EMT', 'Cu500 periodic', asap3.EMT),
    ('asap3 LennardJones', 'Ar500 periodic',
     lambda: asap3.LennardJones([18], [0.0104], [3.4], rCut=8.5,
                                modified=True)),
]


def noise(make_atoms, make_calc, trials, rng):
    atoms = make_atoms()
    atoms.rattle(0.1, seed=3)
    x_nc = atoms.positions.copy()
    atoms.calc = make_calc()
    reference = atoms.get_forces().copy()
    worst = []
    for _ in range(trials):
        other = atoms.copy()
        other.calc = make_calc()
        other.positions = x_nc + rng.normal(0, 0.25, x_nc.shape)
        other.get_forces()
        other.positions = x_nc + rng.normal(0, 0.05, x_nc.shape)
        other.get_forces()
        other.positions = x_nc
        worst.append(np.abs(other.get_forces() - reference).max())
    return worst


def cost(make_atoms, make_calc, rounds, rng):
    atoms = make_atoms()
    atoms.rattle(0.1, seed=3)
    x_nc = atoms.positions.copy()
    atoms.calc = make_calc()
    atoms.get_forces()
    plain, fresh = [], []
    for _ in range(rounds):
        atoms.positions = x_nc + rng.normal(0, 1e-3, x_nc.shape)
        tic = time.perf_counter()
        atoms.get_forces()
        plain.append(time.perf_counter() - tic)
        atoms.positions = x_nc + rng.normal(0, 1e-3, x_nc.shape)
        tic = time.perf_counter()
        atoms.calc = make_calc()
        atoms.get_forces()
        fresh.append(time.perf_counter() - tic)
    return np.median(plain), np.median(fresh)


def main():
    rng = np.random.default_rng(1)
    print('| calculator | system | max force difference per trial (eV/Å) '
          '| force call (ms) | with a fresh neighbour list (ms) | ratio |')
    print('| --- | --- | --- | --- | --- | --- |')
    for name, system, make_calc in CALCULATORS:
        diffs = noise(SYSTEMS[system], make_calc, 5, rng)
        plain, fresh = cost(SYSTEMS[system], make_calc, 9, rng)
        print(f'| {name} | {system} | '
              f'{", ".join(f"{d:.1e}" for d in diffs)} | {plain * 1e3:.2f} '
              f'| {fresh * 1e3:.2f} | {fresh / plain:.1f} |')


if __name__ == '__main__':
    main()
