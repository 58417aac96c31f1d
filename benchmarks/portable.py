"""What the portable arithmetic costs: the package's calculators and the
kinetic energy with the kernels before and after.

A section of ``run_all.py``::

    python benchmarks/run_all.py --only portable           # a few minutes
    python benchmarks/run_all.py --quick --only portable   # < 1 minute

The package's calculators now compute with products, ``sqrt`` and
fixed-order sums only, the same bits on every CPU
(``ase_reversible/core/portable.py``).  Their kernels before that change
(numpy powers such as ``(sigma / r)**6``, ``einsum`` row sums, a BLAS
``@`` for image shifts) are kept here, as subclasses that put back only
the old arithmetic, so both run in one process on the same atoms:

1. Force call: ``get_forces`` at positions alternating between two sets
   (so no cache answers), old and new in interleaved blocks, the order
   rotating from round to round; the median per-call time of each.
2. Step: ``ReversibleVerlet`` steps with each calculator, ten per ``run``
   call, interleaved the same way.  The integrator is today's in both: only the calculator
   differs.
3. ``momentum_square`` (``sum p**2 / m``, which Nosé's thermostat kick
   and the energy check read): the BLAS dot it was against the ``np.sum``
   it is.

Timings are per call, medians over rounds; the load average is stored
beside them.
"""

from __future__ import annotations

import common  # noqa: F401  (first: pins BLAS threads before numpy)

import os
import statistics
import time
import warnings

import numpy as np
from ase import units
from ase.cluster import Icosahedron

from ase_reversible import (LennardJones, PendulumChain, ReversibleVerlet,
                            SoftenedGravity)
from ase_reversible.app.systems import AR_EPSILON, AR_SIGMA, thermalize
from ase_reversible.calculators import make_chain, make_ring
from ase_reversible.calculators import chain as chain_module

FULL = {'rounds': 9, 'block_seconds': 0.2,
        'lj_shells': (3, 4, 5, 6), 'ring_sizes': (32, 128, 512),
        'chain_links': (16, 256, 4096), 'step_cases': 3}
QUICK = {'rounds': 3, 'block_seconds': 0.03,
         'lj_shells': (3, 4), 'ring_sizes': (32, 128),
         'chain_links': (16, 256), 'step_cases': 1}


# -- the kernels as they were ----------------------------------------------

class OldLennardJones(LennardJones):
    """The package's LennardJones with its arithmetic before portability."""

    def _pair_terms(self, r_p, second):
        epsilon, sigma = self.parameters['epsilon'], self.parameters['sigma']
        s6_p = (sigma / r_p)**6
        s12_p = s6_p * s6_p
        phi_p = 4 * epsilon * (s12_p - s6_p)
        dphi_p = 4 * epsilon * (-12 * s12_p + 6 * s6_p) / r_p
        switch_p, dswitch_p, d2switch_p = self._switch(r_p)
        u_p = phi_p * switch_p
        du_p = dphi_p * switch_p + phi_p * dswitch_p
        if not second:
            return u_p, du_p, None
        d2phi_p = 4 * epsilon * (156 * s12_p - 42 * s6_p) / r_p**2
        return u_p, du_p, (d2phi_p * switch_p + 2 * dphi_p * dswitch_p
                           + phi_p * d2switch_p)

    def _switch(self, r_p):
        ro, rc = self.cutoffs
        width = rc - ro
        t_p = np.clip((r_p - ro) / width, 0.0, 1.0)
        switch_p = 1 - t_p**3 * (10 - 15 * t_p + 6 * t_p**2)
        dswitch_p = -30 * t_p**2 * (1 - t_p)**2 / width
        d2switch_p = -60 * t_p * (1 - t_p) * (1 - 2 * t_p) / width**2
        return switch_p, dswitch_p, d2switch_p

    def _pair_geometry(self, atoms):
        x_nc = atoms.positions
        key = x_nc.tobytes()
        if self._pairs is not None and self._pairs[0] == key:
            return self._pairs[1:]
        i_p, j_p, shift_pc = self._candidates(atoms)
        d_pc = x_nc[j_p] - x_nc[i_p] + shift_pc
        r_p = np.sqrt(np.einsum('pc,pc->p', d_pc, d_pc))
        inside_p = r_p < self.cutoffs[1]
        geometry = (i_p[inside_p], j_p[inside_p], d_pc[inside_p],
                    r_p[inside_p])
        self._pairs = (key,) + geometry
        return geometry


class OldSoftenedGravity(SoftenedGravity):
    """SoftenedGravity with its ``einsum`` row sums."""

    def _pair_terms(self, atoms):
        n = len(atoms)
        if self._pairs[0] != n:
            self._pairs = (n, *np.triu_indices(n, k=1))
        _, i_p, j_p = self._pairs
        x_nc = atoms.positions
        m_n = atoms.get_masses()
        d_pc = x_nc[j_p] - x_nc[i_p]
        eps = self.parameters['softening']
        s_p = np.einsum('pc,pc->p', d_pc, d_pc) + eps * eps
        gmm_p = self.parameters['G'] * m_n[i_p] * m_n[j_p]
        return i_p, j_p, d_pc, s_p, gmm_p


class OldPendulumChain(PendulumChain):
    """PendulumChain with its ``einsum`` link lengths and ``**2``."""

    def calculate(self, atoms=None, properties=('energy',),
                  system_changes=()):
        super(PendulumChain, self).calculate(atoms, properties,
                                             system_changes)
        atoms = self.atoms
        k = self.parameters['stiffness']
        g = self.parameters['gravity']
        x_nc = atoms.positions
        m_n = atoms.get_masses()
        d_lc = x_nc[1:] - x_nc[:-1]
        r_l = np.sqrt(np.einsum('lc,lc->l', d_lc, d_lc))
        stretch_l = r_l - self.parameters['rest_length']
        u_l = 0.5 * k * stretch_l**2
        t_lc = chain_module._tension(k * stretch_l, r_l, d_lc)
        f_nc = chain_module._onto_atoms(t_lc, len(atoms))
        f_nc[:, 2] -= m_n * g
        height_n = m_n * g * x_nc[:, 2]
        energies_n = height_n.copy()
        energies_n[:-1] += 0.5 * u_l
        energies_n[1:] += 0.5 * u_l
        self.store_results(float(np.sum(u_l) + np.sum(height_n)),
                           energies_n, f_nc)


# -- systems ------------------------------------------------------------------

def argon(shells):
    atoms = Icosahedron('Ar', shells, latticeconstant=5.26)
    atoms.center(vacuum=10.0)
    return thermalize(atoms, 80, 1)


def cases(settings):
    """(name, atoms builder, old calculator, new calculator, time step)."""
    lj = {'epsilon': AR_EPSILON, 'sigma': AR_SIGMA, 'rc': 8.5}
    for shells in settings['lj_shells']:
        yield ('LennardJones', lambda s=shells: argon(s),
               lambda: OldLennardJones(**lj), lambda: LennardJones(**lj),
               5 * units.fs)
    for n in settings['ring_sizes']:
        yield ('SoftenedGravity', lambda n=n: make_ring(n, spin=0.5,
                                                        jitter=0.3),
               OldSoftenedGravity, SoftenedGravity, 0.05)
    for n in settings['chain_links']:
        yield ('PendulumChain', lambda n=n: make_chain(n), OldPendulumChain,
               PendulumChain, 0.01)


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


#: Steps per timed call: one ``run`` call of ASE's costs more than a step
#: of a small system.
STEPS_PER_CALL = 10


def step_caller(atoms, calc, dt):
    """``STEPS_PER_CALL`` steps of ReversibleVerlet in one ``run``."""
    atoms = atoms.copy()
    atoms.calc = calc
    with warnings.catch_warnings():
        warnings.simplefilter('ignore')
        dyn = ReversibleVerlet(atoms, dt, energy_check=0)
    return lambda: dyn.run(STEPS_PER_CALL)


def momentum_square_callers(n_atoms):
    """The old BLAS dot and the new ``np.sum`` of ``(p / sqrt m)**2``."""
    rng = np.random.default_rng(0)
    p_k = rng.normal(size=3 * n_atoms)
    root_k = np.repeat(1.0 / np.sqrt(rng.uniform(1, 40, n_atoms)), 3)
    v_k = np.empty_like(p_k)

    def old():
        np.multiply(p_k, root_k, out=v_k)
        return float(np.dot(v_k, v_k))

    def new():
        np.multiply(p_k, root_k, out=v_k)
        np.multiply(v_k, v_k, out=v_k)
        return float(np.sum(v_k))
    return {'old': old, 'new': new}


def run(quick) -> dict:
    settings = QUICK if quick else FULL
    rounds, block = settings['rounds'], settings['block_seconds']
    load_before = os.getloadavg()[0]
    forces, steps, kinetic = [], [], []
    step_done = {}
    for name, build, old, new, dt in cases(settings):
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
        if step_done.get(name, 0) < settings['step_cases']:
            step_done[name] = step_done.get(name, 0) + 1
            times = interleaved({'old': step_caller(atoms, old(), dt),
                                 'new': step_caller(atoms, new(), dt)},
                                rounds, block)
            steps.append({'calculator': name, 'n_atoms': len(atoms),
                          'old_seconds': times['old'] / STEPS_PER_CALL,
                          'new_seconds': times['new'] / STEPS_PER_CALL})
    for n_atoms in (55, 1000, 10000):
        times = interleaved(momentum_square_callers(n_atoms), rounds, block)
        kinetic.append({'n_atoms': n_atoms, 'old_seconds': times['old'],
                        'new_seconds': times['new']})
    return {'settings': settings, 'forces': forces, 'steps': steps,
            'momentum_square': kinetic,
            'load_average': [load_before, os.getloadavg()[0]]}
