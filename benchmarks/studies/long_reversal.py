"""Long exact-reversal runs with ASE's pure-Python LennardJones: the test
suite's 20,000-step hot Ar147 round trip, which takes minutes per scheme
with it."""

from __future__ import annotations

import common  # noqa: F401  (first: pins BLAS threads before numpy)

import time

import numpy as np
from ase import units

from ase_reversible import ReversibleVerlet
from ase_reversible.app.systems import argon_cluster, argon_lj

SHELLS, TEMPERATURE_K, TIMESTEP_FS = 4, 120.0, 5.0
SCHEMES = ('velocity', 'position')


def round_trip(scheme, steps):
    atoms = argon_cluster(SHELLS, TEMPERATURE_K)
    atoms.calc = argon_lj()
    dyn = ReversibleVerlet(atoms, TIMESTEP_FS * units.fs, scheme=scheme)
    x0, p0 = atoms.get_positions(), atoms.get_momenta()
    tic = time.perf_counter()
    dyn.run(steps)
    furthest = float(np.abs(atoms.positions - x0).max())
    dyn.reverse()
    dyn.run(steps)
    exact = bool(np.array_equal(atoms.positions, x0)
                 and np.array_equal(atoms.get_momenta(), p0))
    return {'scheme': scheme, 'steps': steps, 'exact': exact,
            'largest_displacement_at_turn': furthest,
            'seconds': time.perf_counter() - tic}


def run(quick):
    steps = 200 if quick else 20000
    return {'atoms': len(argon_cluster(SHELLS, TEMPERATURE_K)),
            'temperature_K': TEMPERATURE_K, 'timestep_fs': TIMESTEP_FS,
            'runs': [round_trip(scheme, steps) for scheme in SCHEMES]}
