"""What the portable arithmetic costs: the package's force calls with the
kernels before and after, in one process.

The old kernels (numpy powers such as ``(sigma / r)**6``, ``einsum`` row
sums) are swapped into the package's modules while an old calculator
computes.
"""

from __future__ import annotations

import common  # noqa: F401  (first: pins BLAS threads before numpy)

import contextlib
import os
import statistics
import time

import numpy as np
from ase.cluster import Icosahedron

from ase_reversible import LennardJones, PendulumChain, SoftenedGravity
from ase_reversible.app.systems import AR_EPSILON, AR_SIGMA, thermalize
from ase_reversible.calculators import (chain, gravity, lennardjones,
                                        make_chain, make_ring)

FULL = {'rounds': 9, 'block_seconds': 0.2,
        'lj_shells': (3, 4, 5, 6), 'ring_sizes': (32, 128, 512),
        'chain_links': (16, 256, 4096)}
QUICK = {'rounds': 3, 'block_seconds': 0.03,
         'lj_shells': (3, 4), 'ring_sizes': (32, 128),
         'chain_links': (16, 256)}


# -- the kernels as they were ----------------------------------------------

def einsum_rowsquare(a_pc):
    return np.einsum('pc,pc->p', a_pc, a_pc)


def numpy_powers(s_p):
    s6_p = s_p**6
    return s6_p, s6_p * s6_p


@contextlib.contextmanager
def old_kernels(module, **kernels):
    """``module``'s functions named in ``kernels`` replaced while inside."""
    saved = {name: getattr(module, name) for name in kernels}
    for name, kernel in kernels.items():
        setattr(module, name, kernel)
    try:
        yield
    finally:
        for name, kernel in saved.items():
            setattr(module, name, kernel)


class OldLennardJones(LennardJones):
    """The package's LennardJones with numpy powers and einsum row sums."""

    def calculate(self, *args, **kwargs):
        with old_kernels(lennardjones, rowsquare=einsum_rowsquare,
                         _powers=numpy_powers):
            super().calculate(*args, **kwargs)

    def _switch(self, r_p):
        ro, rc = self.cutoffs
        width = rc - ro
        t_p = np.clip((r_p - ro) / width, 0.0, 1.0)
        return (1 - t_p**3 * (10 - 15 * t_p + 6 * t_p**2),
                -30 * t_p**2 * (1 - t_p)**2 / width,
                -60 * t_p * (1 - t_p) * (1 - 2 * t_p) / width**2)


def with_einsum_rows(cls, module):
    """``cls`` computing with ``module``'s old ``einsum`` row sums."""
    class Old(cls):
        def calculate(self, *args, **kwargs):
            with old_kernels(module, rowsquare=einsum_rowsquare):
                super().calculate(*args, **kwargs)
    return Old


OldSoftenedGravity = with_einsum_rows(SoftenedGravity, gravity)
OldPendulumChain = with_einsum_rows(PendulumChain, chain)


# -- systems ------------------------------------------------------------------

def argon(shells):
    atoms = Icosahedron('Ar', shells, latticeconstant=5.26)
    atoms.center(vacuum=10.0)
    return thermalize(atoms, 80, 1)


def cases(settings):
    """(name, atoms builder, old calculator, new calculator)."""
    lj = {'epsilon': AR_EPSILON, 'sigma': AR_SIGMA, 'rc': 8.5}
    for shells in settings['lj_shells']:
        yield ('LennardJones', lambda s=shells: argon(s),
               lambda: OldLennardJones(**lj), lambda: LennardJones(**lj))
    for n in settings['ring_sizes']:
        yield ('SoftenedGravity', lambda n=n: make_ring(n, spin=0.5,
                                                        jitter=0.3),
               OldSoftenedGravity, SoftenedGravity)
    for n in settings['chain_links']:
        yield ('PendulumChain', lambda n=n: make_chain(n), OldPendulumChain,
               PendulumChain)


# -- timing -------------------------------------------------------------------

def calls_per_block(call, seconds):
    """How many calls of ``call`` take about ``seconds`` (after one call
    to warm up)."""
    call()
    started, calls = time.perf_counter(), 0
    while time.perf_counter() - started < seconds / 4 or calls < 2:
        call()
        calls += 1
    return max(2, int(4 * calls))


def interleaved(contestants, rounds, block_seconds):
    """{name: median seconds per call}: blocks of each contestant's calls,
    interleaved, the order rotating from round to round."""
    names = list(contestants)
    sizes = {name: calls_per_block(contestants[name], block_seconds)
             for name in names}
    times = {name: [] for name in names}
    for r in range(rounds):
        for name in names[r % len(names):] + names[:r % len(names)]:
            call, n = contestants[name], sizes[name]
            started = time.perf_counter()
            for _ in range(n):
                call()
            times[name].append((time.perf_counter() - started) / n)
    return {name: statistics.median(t) for name, t in times.items()}


def force_caller(atoms, calc):
    """A call of ``get_forces`` at positions alternating between two sets."""
    atoms = atoms.copy()
    atoms.calc = calc
    x0_nc = atoms.positions.copy()
    x1_nc = x0_nc + 1e-6
    which = [0]

    def call():
        which[0] ^= 1
        atoms.positions = x1_nc if which[0] else x0_nc
        atoms.get_forces()
    call()
    return call


def run(quick) -> dict:
    settings = QUICK if quick else FULL
    rounds, block = settings['rounds'], settings['block_seconds']
    load_before = os.getloadavg()[0]
    forces = []
    for name, build, old, new in cases(settings):
        atoms = build()
        times = interleaved({'old': force_caller(atoms, old()),
                             'new': force_caller(atoms, new())},
                            rounds, block)
        forces.append({'calculator': name, 'n_atoms': len(atoms),
                       'old_seconds': times['old'],
                       'new_seconds': times['new']})
        print(f"  {name} {len(atoms)} atoms: force call "
              f"{times['old'] * 1e3:.3f} -> {times['new'] * 1e3:.3f} ms",
              flush=True)
    return {'settings': settings, 'forces': forces,
            'load_average': [load_before, os.getloadavg()[0]]}
