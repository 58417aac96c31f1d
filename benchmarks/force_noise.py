"""Force history noise of each calculator, and what a neighbour-list
rebuild costs."""

from __future__ import annotations

import common  # noqa: F401  (first: pins BLAS threads before numpy)

import time

import numpy as np
from systems import CALCULATORS

from ase_reversible.app.systems import argon_bulk, copper_bulk

#: The calculators by the labels of the table, with their system.
CASES = (('ASE EMT', 'Cu500 periodic'), ('ASE LJ', 'Ar500 periodic'),
         ('asap3 EMT', 'Cu500 periodic'), ('asap3 LJ', 'Ar500 periodic'))
RATTLE, RATTLE_SEED = 0.1, 3


def build(system):
    """Rattled 5x5x5 cubic crystals; only the positions are used."""
    if system == 'Cu500 periodic':
        return copper_bulk((5, 5, 5), 300, seed=RATTLE_SEED, rattle=RATTLE)
    atoms = argon_bulk((5, 5, 5), 60)
    atoms.rattle(RATTLE, seed=RATTLE_SEED)
    return atoms


def noise(system, make_calc, trials, rng):
    atoms = build(system)
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
        worst.append(float(np.abs(other.get_forces() - reference).max()))
    return worst


def cost(system, make_calc, rounds, rng):
    atoms = build(system)
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
    return float(np.median(plain)), float(np.median(fresh))


def run(quick):
    trials, rounds = (2, 3) if quick else (5, 9)
    rng = np.random.default_rng(1)
    rows = []
    for name, system in CASES:
        diffs = noise(system, CALCULATORS[name], trials, rng)
        plain, fresh = cost(system, CALCULATORS[name], rounds, rng)
        rows.append({'calculator': name, 'system': system,
                     'max_force_difference': diffs,
                     'force_call_seconds': plain,
                     'fresh_list_seconds': fresh})
    return {'trials': trials, 'rounds': rounds, 'rows': rows}
