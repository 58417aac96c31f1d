"""The reversible adjoint: memory against steps (a process per point,
``--memory-worker``), and the cost of a gradient in force calls and time;
the method is docs/benchmarks.md's."""

from __future__ import annotations

import common  # noqa: F401  (first: pins BLAS threads before numpy)

import gc
import json
import statistics
import sys
import time
import tracemalloc
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
from ase import units
from ase.md.velocitydistribution import Stationary
from harness import choose_steps, max_rss_bytes

from ase_reversible import (AnalyticHVP, FiniteDifferenceHVP, LennardJones,
                            ReversibleVerlet)
from ase_reversible.app import systems

TIMESTEP_FS = 5.0
TIMESTEP = TIMESTEP_FS * units.fs
SEED = 0

#: The memory system: Ar13 icosahedron, cold.
MEMORY_SHELLS, MEMORY_TEMPERATURE_K = 2, 5.0
MEMORY_STEPS = {False: (1000, 10_000, 100_000), True: (100, 1000)}
MEMORY_KINDS = ('reversible', 'stored')
#: Memory workers running at once.
MEMORY_PARALLEL = 2

AR_COST_SHELLS, AR_COST_TEMPERATURE_K = 4, 60.0   # Ar147
CU_REPEAT, CU_TEMPERATURE_K = (4, 4, 4), 300.0     # Cu256, periodic


@dataclass(frozen=True)
class CostCase:
    label: str
    system: str        # 'ar147' or 'cu256'
    calculator: str    # 'lj', 'emt', 'asap3'
    hvp: str           # as passed to backpropagate
    scheme: str = 'velocity'
    order: int = 2


COST_CASES = (
    CostCase('Ar147, LennardJones, analytic', 'ar147', 'lj', 'analytic'),
    CostCase('Ar147, LennardJones, analytic', 'ar147', 'lj', 'analytic',
             scheme='position'),
    CostCase('Ar147, LennardJones, analytic', 'ar147', 'lj', 'analytic',
             order=4),
    CostCase('Ar147, LennardJones, finite differences', 'ar147', 'lj',
             'finite-difference'),
    CostCase('Cu256, ASE EMT, finite differences', 'cu256', 'emt', 'auto'),
    CostCase('Cu256, asap3 EMT, finite differences', 'cu256', 'asap3',
             'auto'),
)


@dataclass(frozen=True)
class Settings:
    rounds: int           # timed rounds
    counting_rounds: int  # rounds with every call counted, before those
    block_seconds: float  # target wall time of one forward block
    min_steps: int
    max_steps: int
    warmup_steps: int


FULL = Settings(rounds=7, counting_rounds=3, block_seconds=0.5,
                min_steps=5, max_steps=2000, warmup_steps=5)
QUICK = Settings(rounds=2, counting_rounds=1, block_seconds=0.05,
                 min_steps=3, max_steps=200, warmup_steps=3)


# -- systems ------------------------------------------------------------------

def argon_cluster(shells, temperature_K, stationary=False):
    atoms = systems.argon_cluster(shells, temperature_K, SEED)
    if stationary:
        # No net momentum: otherwise the cluster drifts through and out of
        # its cell over a long run, and the temporaries of the neighbour
        # search, which span the atoms' extent, grow with the drift.
        Stationary(atoms)
    atoms.calc = LennardJones(epsilon=systems.AR_EPSILON,
                              sigma=systems.AR_SIGMA)
    return atoms


def copper_crystal(calculator):
    atoms = systems.copper_bulk(CU_REPEAT, CU_TEMPERATURE_K, SEED, rattle=0)
    if calculator == 'emt':
        from ase.calculators.emt import EMT
        atoms.calc = EMT()
    else:
        import asap3
        atoms.calc = asap3.EMT()
    return atoms


def loss_gradient(n_atoms):
    """dL/dx and dL/dp of a fixed random linear loss on the final state."""
    rng = np.random.default_rng(SEED + 1)
    return rng.standard_normal((n_atoms, 3)), rng.standard_normal((n_atoms, 3))


# -- memory -------------------------------------------------------------------

def stored_adjoint(atoms, frames, masses_n1, h, grad_x, grad_p):
    """The adjoint of kick-drift-kick over stored positions ``frames``.

    ``frames[k]`` is the positions after step k (``frames[0]`` the start).
    The same arithmetic as :class:`ase_reversible.adjoint.Adjoint` in the
    same order (the two kicks at one position merged into one product),
    so a difference from ``backpropagate`` can only come from the
    positions the products are taken at.  Returns ``(dL/dx0, dL/dp0,
    products)``.
    """
    hvp = atoms.calc.hessian_vector_product
    ax_nc, ap_nc = np.array(grad_x, dtype=float), np.array(grad_p, dtype=float)
    w_nc = np.empty_like(ax_nc)
    products = 0

    def kicks(k, ch):
        nonlocal products
        atoms.positions = frames[k]
        w_nc[:] = ap_nc
        ax_nc[:] -= ch * np.asarray(hvp(atoms, w_nc), dtype=float)
        products += 1

    for k in range(len(frames) - 1, 0, -1):
        # At x_k: the last kick of step k (and the first of step k + 1).
        kicks(k, 0.5 * h if k == len(frames) - 1 else h)
        # The drift of step k.
        np.divide(ax_nc, masses_n1, out=w_nc)
        w_nc *= h
        ap_nc += w_nc
    kicks(0, 0.5 * h)
    return ax_nc, ap_nc, products


def memory_worker(kind, steps):
    """One memory point, in a process of its own; prints a JSON line."""
    atoms = argon_cluster(MEMORY_SHELLS, MEMORY_TEMPERATURE_K,
                          stationary=True)
    dyn = ReversibleVerlet(atoms, TIMESTEP)
    x0_nc, p0_nc = atoms.get_positions(), atoms.get_momenta()
    masses_n1 = atoms.get_masses()[:, None]
    grad_x, grad_p = loss_gradient(len(atoms))
    gc.collect()
    rss_before = max_rss_bytes()
    tracemalloc.start()
    t0 = time.perf_counter()
    result = {'kind': kind, 'steps': steps, 'atoms': len(atoms)}
    com0_c = atoms.get_center_of_mass()
    frames, momenta = [], []
    if kind == 'stored':
        def store():
            frames.append(atoms.positions.copy())
            momenta.append(atoms.get_momenta())  # a copy

        dyn.attach(store, interval=1)  # also called before the first step
    dyn.run(steps)
    t1 = time.perf_counter()
    result['centre_of_mass_moved'] = float(np.linalg.norm(
        atoms.get_center_of_mass() - com0_c))
    if kind == 'reversible':
        g = dyn.backpropagate(steps, grad_x, grad_p)
        (gx_nc, gp_nc), result['products'] = g, g.hessian_vector_products
        result['exact_return'] = bool(
            np.array_equal(atoms.positions, x0_nc)
            and np.array_equal(atoms.get_momenta(), p0_nc))
    else:
        gx_nc, gp_nc, result['products'] = stored_adjoint(
            atoms, frames, masses_n1, TIMESTEP, grad_x, grad_p)
        result['frames'] = len(frames)
        result['exact_return'] = None
    result['stored_bytes'] = sum(a.nbytes for a in frames + momenta)
    t2 = time.perf_counter()
    current, peak = tracemalloc.get_traced_memory()
    result.update(
        traced_peak_bytes=peak, traced_end_bytes=current,
        tracemalloc_own_bytes=tracemalloc.get_tracemalloc_memory(),
        forward_seconds=t1 - t0, gradient_seconds=t2 - t1)
    tracemalloc.stop()
    result.update(max_rss_before_bytes=rss_before,
                  max_rss_bytes=max_rss_bytes(),
                  gradient_positions=gx_nc.tolist(),
                  gradient_momenta=gp_nc.tolist())
    print(json.dumps(result), flush=True)


def measure_memory(quick):
    steps = MEMORY_STEPS[quick]
    jobs = sorted(((kind, n) for n in steps for kind in MEMORY_KINDS),
                  key=lambda job: -job[1])  # longest first
    raw = dict(zip(jobs, common.run_workers(Path(__file__), jobs,
                                            MEMORY_PARALLEL)))
    points = []
    for n in steps:
        ours, stored = raw['reversible', n], raw['stored', n]
        g_ours = np.array([ours.pop('gradient_positions'),
                           ours.pop('gradient_momenta')])
        g_stored = np.array([stored.pop('gradient_positions'),
                             stored.pop('gradient_momenta')])
        scale = float(np.abs(g_ours).max())
        points.append({
            'steps': n, 'reversible': ours, 'stored': stored,
            'gradients_bitwise_equal': bool(np.array_equal(g_ours, g_stored)),
            'gradient_max_relative_difference':
                float(np.abs(g_ours - g_stored).max() / scale),
            'gradient_max_abs': scale,
        })
    return {'system': {'cluster': f'Ar{points[0]["reversible"]["atoms"]} '
                                  'icosahedron',
                       'temperature_K': MEMORY_TEMPERATURE_K,
                       'calculator': 'ase_reversible.LennardJones '
                                     f'(epsilon={systems.AR_EPSILON}, '
                                     f'sigma={systems.AR_SIGMA})',
                       'timestep_fs': TIMESTEP_FS, 'seed': SEED},
            'parallel_workers': MEMORY_PARALLEL,
            'points': points}


# -- cost ---------------------------------------------------------------------

class CallCounter:
    """Counts and times the force calls that compute, on one calculator."""

    def __init__(self, calc):
        self.calc = calc
        self.in_hvp = False
        self.reset()
        self._get_forces = calc.get_forces
        calc.get_forces = self.get_forces

    def get_forces(self, atoms=None, *args, **kwargs):
        if not self.calc.calculation_required(atoms, ['forces']):
            return self._get_forces(atoms, *args, **kwargs)
        self.forces['hvp' if self.in_hvp else 'direct'] += 1
        t0 = time.perf_counter()
        try:
            return self._get_forces(atoms, *args, **kwargs)
        finally:
            self.force_seconds += time.perf_counter() - t0

    def reset(self):
        self.forces = {'direct': 0, 'hvp': 0}
        self.force_seconds = 0.0

    def remove(self):
        del self.calc.get_forces


class CountingHVP:
    """Wraps a Hessian-vector product: counts, times, flags force calls."""

    def __init__(self, inner, counter):
        self.inner, self.counter = inner, counter
        self.calls, self.seconds = 0, 0.0

    def __call__(self, atoms, v_nc):
        self.counter.in_hvp = True
        t0 = time.perf_counter()
        try:
            return self.inner(atoms, v_nc)
        finally:
            self.seconds += time.perf_counter() - t0
            self.counter.in_hvp = False
            self.calls += 1


def product(case, calc):
    """The Hessian-vector product ``backpropagate(hvp=case.hvp)`` uses with
    ``calc``, as an object the counting wrapper can hold."""
    analytic = callable(getattr(calc, 'hessian_vector_product', None))
    if case.hvp == 'analytic' or (case.hvp == 'auto' and analytic):
        return AnalyticHVP()
    return FiniteDifferenceHVP()


def build_cost_case(case):
    if case.system == 'ar147':
        atoms = argon_cluster(AR_COST_SHELLS, AR_COST_TEMPERATURE_K)
    else:
        atoms = copper_crystal(case.calculator)
    dyn = ReversibleVerlet(atoms, TIMESTEP, scheme=case.scheme,
                           order=case.order)
    return atoms, dyn


def counted_round(dyn, atoms, case, steps, grad_x, grad_p):
    """One run(steps) + backpropagate(steps) with every call counted."""
    counter = CallCounter(atoms.calc)
    try:
        dyn.run(steps)
        forward = {'force_calls': counter.forces['direct'],
                   'force_seconds': counter.force_seconds}
        counter.reset()
        hvp = CountingHVP(product(case, atoms.calc), counter)
        t1 = time.perf_counter()
        dyn.backpropagate(steps, grad_x, grad_p, hvp=hvp)
        backward = {'force_calls_retrace': counter.forces['direct'],
                    'force_calls_in_products': counter.forces['hvp'],
                    'products': hvp.calls, 'product_seconds': hvp.seconds,
                    'seconds': time.perf_counter() - t1}
    finally:
        counter.remove()
    return {'forward': forward, 'backward': backward,
            'hvp_class': type(hvp.inner).__name__}


def measure_cost_case(case, settings):
    atoms, dyn = build_cost_case(case)
    dyn.run(settings.warmup_steps)
    # A fifth of a block resolves the forward run well enough.
    steps = choose_steps(dyn.run, settings, resolution=5)
    grad_x, grad_p = loss_gradient(len(atoms))
    x0_nc, p0_nc = atoms.get_positions(), atoms.get_momenta()

    def back_at_start():
        return bool(np.array_equal(atoms.positions, x0_nc)
                    and np.array_equal(atoms.get_momenta(), p0_nc))

    # Counting rounds first (the first is also a warm-up of a whole round).
    counted = []
    exact = []
    for _ in range(settings.counting_rounds):
        counted.append(counted_round(dyn, atoms, case, steps, grad_x,
                                     grad_p))
        exact.append(back_at_start())
    samples = {'forward_wall': [], 'backward_wall': [], 'forward_cpu': [],
               'backward_cpu': []}
    for _ in range(settings.rounds):
        w0, c0 = time.perf_counter(), time.process_time()
        dyn.run(steps)
        w1, c1 = time.perf_counter(), time.process_time()
        dyn.backpropagate(steps, grad_x, grad_p, hvp=case.hvp)
        w2, c2 = time.perf_counter(), time.process_time()
        exact.append(back_at_start())
        for key, seconds in (('forward_wall', w1 - w0),
                             ('backward_wall', w2 - w1),
                             ('forward_cpu', c1 - c0),
                             ('backward_cpu', c2 - c1)):
            samples[key].append(seconds / steps)
    forward_wall, backward_wall = (samples['forward_wall'],
                                   samples['backward_wall'])
    fwd = statistics.median(forward_wall)
    bwd = statistics.median(backward_wall)

    def total(direction, key):
        return sum(r[direction][key] for r in counted)

    covered = len(counted) * steps  # steps covered by the counting rounds
    per_force = [r['forward']['force_seconds'] / r['forward']['force_calls']
                 for r in counted if r['forward']['force_calls']]
    per_product = [r['backward']['product_seconds']
                   / r['backward']['products']
                   for r in counted if r['backward']['products']]
    return {
        **asdict(case), 'atoms': len(atoms), 'steps_per_block': steps,
        'rounds': settings.rounds, 'counting_rounds': len(counted),
        'hvp_class': counted[0]['hvp_class'],
        'per_step': {
            f'{direction}_{key}': total(direction, key) / covered
            for direction, keys in (
                ('forward', ('force_calls',)),
                ('backward', ('force_calls_retrace', 'force_calls_in_products',
                              'products')))
            for key in keys},
        'product_over_force_call_time':
            statistics.median(per_product) / statistics.median(per_force)
            if per_product and per_force else None,
        'backward_share_in_products': statistics.median(
            r['backward']['product_seconds'] / r['backward']['seconds']
            for r in counted),
        'exact_return_every_round': all(exact), 'rounds_checked': len(exact),
        'forward_ms_per_step': 1e3 * fwd, 'backward_ms_per_step': 1e3 * bwd,
        'backward_over_forward': bwd / fwd,
        'spread': max((max(v) - min(v)) / statistics.median(v)
                      for v in (forward_wall, backward_wall)),
        'wall_over_cpu': max(fwd / statistics.median(samples['forward_cpu']),
                             bwd / statistics.median(samples['backward_cpu'])),
        'samples': samples,
    }


def measure_cost(quick):
    settings = QUICK if quick else FULL
    cases = []
    for case in COST_CASES:
        print(f'  cost: {case.label}, {case.scheme} scheme, order {case.order}',
              flush=True)
        cases.append(measure_cost_case(case, settings))
    return {'settings': asdict(settings), 'cases': cases}


# -- run ----------------------------------------------------------------------

def run(quick):
    print('  memory workers', flush=True)
    memory = measure_memory(quick)
    cost = measure_cost(quick)
    results = {'timestep_fs': TIMESTEP_FS, 'memory': memory, 'cost': cost,
               'cost_systems': {
                   'ar147': f'Ar147 icosahedron, free boundaries, '
                            f'{AR_COST_TEMPERATURE_K:g} K, '
                            'ase_reversible.LennardJones '
                            f'(epsilon={systems.AR_EPSILON}, '
                            f'sigma={systems.AR_SIGMA})',
                   'cu256': 'Cu256 fcc crystal (4x4x4 cubic cells), '
                            f'periodic, {CU_TEMPERATURE_K:g} K'}}
    return results


if __name__ == '__main__' and sys.argv[1:2] == ['--memory-worker']:
    memory_worker(sys.argv[2], int(sys.argv[3]))
