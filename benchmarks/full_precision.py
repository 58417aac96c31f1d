"""What full precision under asap3 would take: the history noise a
'guarded' run meets, the momentum quanta, the share of kicks in the guard
band, and a clean recomputation's cost in force calls."""

from __future__ import annotations

import common  # noqa: F401  (first: pins BLAS threads before numpy)

import math
import time

import numpy as np
from ase import units
from systems import CALCULATORS

from ase_reversible import ReversibleVerlet
from ase_reversible.app.systems import argon_cluster, copper_bulk
from ase_reversible.purity import GuardedForces, TARGET_CLEAN_RATE
from ase_reversible.purity.settings import guarded_momentum_quantum

DT_FS = 5


def cu_free(cells):
    atoms = copper_bulk(cells, 300)
    atoms.pbc = False
    atoms.center(vacuum=10.0)
    return atoms


#: (label, calculator, builder).
CASES = (
    ('Ar147 free cluster, 40 K', 'asap3 LJ', lambda: argon_cluster(4, 40)),
    ('Cu500 free block, 300 K', 'asap3 EMT', lambda: cu_free((5, 5, 5))),
    ('Cu500 periodic, 300 K', 'asap3 EMT',
     lambda: copper_bulk((5, 5, 5), 300)),
    ('Cu4000 periodic, 300 K', 'asap3 EMT',
     lambda: copper_bulk((10, 10, 10), 300)),
)


def run_noise(make, calc, samples):
    """Differences (eV/Å) between the run's forces and clean ones."""
    atoms = make()
    atoms.calc = CALCULATORS[calc]()
    dyn = ReversibleVerlet(atoms, DT_FS * units.fs, force_purity='guarded')
    guard = dyn.force_purity
    found = []

    def sample():
        history = atoms.get_forces(md=True).copy()
        found.append(np.abs(guard.clean_forces(atoms) - history).ravel())

    dyn.attach(sample, interval=10)
    dyn.run(10 * samples)
    return np.concatenate(found), dyn


def clean_cost(make, calc, rounds):
    """Median seconds of a force call and of a clean recomputation at
    slightly moved positions, interleaved."""
    atoms = make()
    atoms.calc = CALCULATORS[calc]()
    atoms.get_forces()
    guard = GuardedForces()
    rng = np.random.default_rng(0)
    x_nc = atoms.positions.copy()
    plain, clean = [], []
    for _ in range(rounds):
        atoms.positions = x_nc + rng.normal(0, 1e-4, x_nc.shape)
        tic = time.perf_counter()
        atoms.get_forces(md=True)
        plain.append(time.perf_counter() - tic)
        atoms.positions = x_nc + rng.normal(0, 1e-4, x_nc.shape)
        tic = time.perf_counter()
        guard.clean_forces(atoms)
        clean.append(time.perf_counter() - tic)
    return float(np.median(plain)), float(np.median(clean))


def quantum(make, calc, purity):
    atoms = make()
    atoms.calc = CALCULATORS[calc]()
    dyn = ReversibleVerlet(atoms, DT_FS * units.fs, force_purity=purity)
    return dyn.grid.momentum_quantum


def run(quick):
    samples, rounds = (5, 5) if quick else (40, 15)
    cases = CASES[:2] if quick else CASES
    rows = []
    for label, calc, make in cases:
        diffs, dyn = run_noise(make, calc, samples)
        n = len(dyn.atoms)
        q_pure = quantum(make, calc, 'trust')
        q_guarded = dyn.grid.momentum_quantum
        worst = float(diffs.max())
        # A kick of the velocity scheme: c h = dt (two merged halves).
        kick = DT_FS * units.fs
        # round_odd has a boundary every 2 quanta; a band of +-bound around
        # each holds a fraction bound / 1 of the components.
        band = kick * worst / q_pure
        p_step = 1.0 - (1.0 - min(band, 1.0))**(3 * n)
        needed = guarded_momentum_quantum(n, worst, kick, 0.0)
        plain, clean = clean_cost(make, calc, rounds)
        rows.append({
            'system': label, 'calculator': calc, 'atoms': n,
            'samples': int(diffs.size),
            'noise_median': float(np.median(diffs)), 'noise_max': worst,
            'force_noise_default': dyn.force_purity.force_noise,
            'q_pure_log2': math.log2(q_pure),
            'q_guarded_log2': math.log2(q_guarded),
            'q_measured_bound_log2': (math.ceil(math.log2(needed))
                                      if worst > 0 else None),
            'band_fraction_at_pure_quantum': band,
            'clean_per_step_at_pure_quantum': p_step,
            'force_call_seconds': plain, 'clean_seconds': clean})
    return {'dt_fs': DT_FS, 'target_clean_rate': TARGET_CLEAN_RATE,
            'rows': rows}
