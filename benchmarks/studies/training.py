"""Training through exact retraces (examples/fit_rdf.py): gradients
against central differences of float runs, memory (one fresh process per
point, ``--memory-worker``) against plain PyTorch autograd, time of an
epoch (``--only training``: ~25 minutes, ~1 with ``--quick``;
``--only training_memory``: the memory alone).
"""

from __future__ import annotations

import common  # noqa: F401  (first: pins BLAS threads before numpy)

import importlib.util
import json
import statistics
import sys
import time
from pathlib import Path

import numpy as np
from harness import max_rss_bytes, resident_bytes

STUDENT_SIGMA, FIXED_RC = 3.6, 8.5
EVERY = 20
GRADIENT_STEPS = {False: 200, True: 100}
FD_STEPS = (1e-4, 1e-5, 1e-6)   # relative
MEMORY_STEPS = {False: {'reversible': (1000, 10_000, 100_000),
                        'autograd': (1000, 3000, 10_000)},
                True: {'reversible': (100, 1000),
                       'autograd': (300, 1000)}}
MEMORY_RC, MEMORY_EVERY = 5.5, 100
TIME_ROUNDS = {False: 5, True: 2}
TIME_STEPS = {False: 400, True: 100}


def example():
    """examples/fit_rdf.py as a module: the pipeline measured is the
    example's own."""
    if 'fit_rdf' in sys.modules:
        return sys.modules['fit_rdf']
    spec = importlib.util.spec_from_file_location(
        'fit_rdf', common.ROOT / 'examples' / 'fit_rdf.py')
    module = importlib.util.module_from_spec(spec)
    sys.modules['fit_rdf'] = module
    spec.loader.exec_module(module)
    return module


class RssSampler:
    """The largest resident set size seen every ``interval`` seconds while
    it runs (``ru_maxrss`` hides it under the imports' peak)."""

    def __init__(self, interval=0.01):
        import threading
        self.interval, self.peak = interval, resident_bytes()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._sample, daemon=True)

    def _sample(self):
        while not self._stop.wait(self.interval):
            now = resident_bytes()
            if now is not None and (self.peak is None or now > self.peak):
                self.peak = now

    def __enter__(self):
        self._thread.start()
        return self

    def __exit__(self, *exc):
        self._stop.set()
        self._thread.join()


# -- gradients ----------------------------------------------------------------

def equilibrated_liquid(fit, steps):
    """32 argon atoms after ``steps`` NVT steps of the reference LJ."""
    from ase_reversible import LennardJones, ReversibleLangevin
    from ase_reversible.core.record import INFO_KEY
    atoms = fit.liquid_argon(2)
    atoms.calc = LennardJones(epsilon=fit.EPSILON, sigma=fit.SIGMA)
    dyn = ReversibleLangevin(atoms, fit.TIMESTEP, fit.TEMPERATURE_K,
                             fit.FRICTION, seed=fit.SEED)
    dyn.run(steps)
    atoms.info.pop(INFO_KEY, None)
    return atoms


class Window:
    """An NVE window of ``steps`` steps from ``atoms``' state with a
    Lennard-Jones of (ε, σ, rc = FIXED_RC): its losses and their gradients
    by one retrace, or by float velocity Verlet."""

    def __init__(self, fit, atoms, steps, target_rdf_b, target_vacf_k):
        self.fit, self.steps = fit, steps
        self.atoms0 = atoms
        self.rdf = fit.SmoothRDF(atoms, fit.QUICK.r_max)
        self.target_rdf_b, self.target_vacf_k = target_rdf_b, target_vacf_k

    def losses(self, observed):
        """``({loss name: L}, what the loss callbacks need)`` from the
        states ``observed``, a list of (x, p) ordered by time."""
        fit = self.fit
        count = len(observed)
        mean_b = sum(self.rdf.values(x) for x, _ in observed) / count
        rdf_loss, dl_b = fit.rdf_loss(mean_b, self.target_rdf_b)
        m_n1 = self.atoms0.get_masses()[:, None]
        v0_nc = observed[0][1] / m_n1
        vacf_k = np.array([np.mean(np.sum(v0_nc * p / m_n1, axis=1))
                           for _, p in observed])
        miss_k = vacf_k - self.target_vacf_k
        x0_nc, xt_nc = observed[0][0], observed[-1][0]
        n = len(x0_nc)
        msd = float(np.sum((xt_nc - x0_nc) ** 2) / n)
        return {'rdf': rdf_loss, 'vacf': float(np.sum(miss_k**2)),
                'msd': msd}, (dl_b / count, miss_k, v0_nc, m_n1, x0_nc)

    def reversible(self, epsilon, sigma):
        """Losses and ``{loss: {param: dL/dparam}}`` by the retrace; and
        whether it came back bit for bit."""
        from ase_reversible import LennardJones, ReversibleVerlet
        fit = self.fit
        atoms = self.atoms0.copy()
        atoms.calc = LennardJones(epsilon=epsilon, sigma=sigma, rc=FIXED_RC)
        dyn = ReversibleVerlet(atoms, fit.TIMESTEP)
        observed = states(dyn, self.steps)
        x_start, p_start = self.start = observed[0]
        values, (w_b, miss_k, v0_nc, m_n1, x0_nc) = self.losses(observed)
        names = ('epsilon', 'sigma')
        grads = {}

        def rdf_point(state, k):
            return self.rdf.pullback(state.positions, w_b), None

        def vacf_point(state, k):
            # dC_k/dp_k = v_i(0) / (m_i N); C_k's dependence on v(0) is
            # the window's start, which θ does not move.
            return None, 2 * miss_k[k // EVERY] * v0_nc / (m_n1 * len(m_n1))

        exact = True
        for name, kwargs in (
                ('rdf', {'loss': rdf_point, 'every': EVERY}),
                ('vacf', {'loss': vacf_point, 'every': EVERY}),
                ('msd', {'grad_positions': 2 * (observed[-1][0] - x0_nc)
                         / len(x0_nc)})):
            if name != 'rdf':
                dyn.run(self.steps)
            g = dyn.backpropagate(self.steps, parameters=names, **kwargs)
            grads[name] = {k: float(v) for k, v in g.parameters.items()}
            exact &= (np.array_equal(atoms.positions, x_start)
                      and np.array_equal(atoms.get_momenta(), p_start))
        return values, grads, exact

    def floating(self, epsilon, sigma):
        """The same losses from ASE's float VelocityVerlet."""
        from ase.md.verlet import VelocityVerlet
        from ase_reversible import LennardJones
        atoms = self.atoms0.copy()
        atoms.positions[:] = self.start[0]
        atoms.set_momenta(self.start[1])
        atoms.calc = LennardJones(epsilon=epsilon, sigma=sigma, rc=FIXED_RC)
        return self.losses(states(VelocityVerlet(atoms, self.fit.TIMESTEP),
                                  self.steps))[0]


def reference_targets(fit, atoms, steps, windows=4):
    """The reference's g(r) and VACF, averaged over float NVE windows
    started ``steps`` NVT steps apart."""
    from ase.md.verlet import VelocityVerlet
    from ase_reversible import LennardJones, ReversibleLangevin
    from ase_reversible.core.record import INFO_KEY
    atoms = atoms.copy()
    atoms.calc = LennardJones(epsilon=fit.EPSILON, sigma=fit.SIGMA)
    rdf = fit.SmoothRDF(atoms, fit.QUICK.r_max)
    m_n1 = atoms.get_masses()[:, None]
    rdf_sum = vacf_sum = 0
    for k in range(windows):
        b = atoms.copy()
        b.calc = atoms.calc
        observed = states(VelocityVerlet(b, fit.TIMESTEP), steps)
        rdf_sum = rdf_sum + sum(rdf.values(x) for x, _ in observed) \
            / len(observed)
        v0_nc = observed[0][1] / m_n1
        vacf_sum = vacf_sum + np.array(
            [np.mean(np.sum(v0_nc * p / m_n1, axis=1)) for _, p in observed])
        atoms.info.pop(INFO_KEY, None)
        ReversibleLangevin(atoms, fit.TIMESTEP, fit.TEMPERATURE_K,
                           fit.FRICTION, seed=fit.SEED + 100 + k).run(steps)
    return rdf_sum / windows, vacf_sum / windows


def states(dyn, steps):
    """[(x, p)] of ``dyn``'s atoms now and every EVERY of ``steps`` steps."""
    atoms = dyn.atoms
    observed = [(atoms.positions.copy(), atoms.get_momenta())]
    for _ in range(steps // EVERY):
        dyn.run(EVERY)
        observed.append((atoms.positions.copy(), atoms.get_momenta()))
    return observed


def measure_gradients(quick):
    fit = example()
    steps = GRADIENT_STEPS[quick]
    atoms = equilibrated_liquid(fit, 300 if quick else 1000)
    target_rdf_b, target_vacf_k = reference_targets(fit, atoms, steps)
    window = Window(fit, atoms, steps, target_rdf_b, target_vacf_k)
    epsilon, sigma = fit.EPSILON, STUDENT_SIGMA
    values, grads, exact = window.reversible(epsilon, sigma)
    checks = []
    for rel in FD_STEPS:
        for name, value in (('epsilon', epsilon), ('sigma', sigma)):
            h = rel * value
            up = window.floating(*((epsilon + h, sigma) if name == 'epsilon'
                                   else (epsilon, sigma + h)))
            down = window.floating(*((epsilon - h, sigma)
                                     if name == 'epsilon'
                                     else (epsilon, sigma - h)))
            for loss in values:
                fd = (up[loss] - down[loss]) / (2 * h)
                ours = grads[loss][name]
                checks.append({'loss': loss, 'parameter': name,
                               'relative_step': rel, 'finite_difference': fd,
                               'retrace': ours,
                               'relative_error': abs(fd - ours) / abs(ours)})
    return {'atoms': len(atoms), 'steps': steps, 'every': EVERY,
            'student': {'epsilon': epsilon, 'sigma': sigma, 'rc': FIXED_RC},
            'exact_return': bool(exact), 'checks': checks}


# -- memory --------------------------------------------------------------------

def memory_worker(kind, steps):
    """One memory point in a process of its own; prints a JSON line."""
    import torch
    torch.set_num_threads(1)
    fit = example()
    from ase_reversible import LennardJones
    atoms = equilibrated_liquid(fit, 0)
    rdf = fit.SmoothRDF(atoms, fit.QUICK.r_max)
    target_b = rdf.values(atoms.positions)
    rss_before = max_rss_bytes()
    rss_now = resident_bytes()
    t0 = time.perf_counter()
    result = {'kind': kind, 'steps': steps, 'atoms': len(atoms)}
    sampler = RssSampler().__enter__()
    if kind == 'reversible':
        size = fit.Size(repeat=2, r_max=fit.QUICK.r_max, equilibrate=0,
                        target_steps=0, epochs=1, steps=steps,
                        every=MEMORY_EVERY, window=MEMORY_EVERY,
                        learning_rate=0, mlp_cutoff=0, mlp_learning_rate=0,
                        pretrain_steps=0)
        calc = LennardJones(epsilon=fit.EPSILON, sigma=STUDENT_SIGMA,
                            rc=MEMORY_RC)
        fit.epoch(atoms, calc, ('epsilon', 'sigma'), rdf, target_b, size,
                  fit.SEED)
    elif kind == 'autograd':
        autograd_epoch(fit, atoms, rdf, target_b, steps)
    else:
        raise ValueError(kind)
    sampler.__exit__()
    result.update(rss_before_bytes=rss_now, rss_peak_bytes=sampler.peak)
    result.update(seconds=time.perf_counter() - t0,
                  max_rss_before_bytes=rss_before,
                  max_rss_bytes=max_rss_bytes())
    print(json.dumps(result), flush=True)


def autograd_epoch(fit, atoms, rdf, target_b, steps):
    """Plain autograd: velocity Verlet in torch, every step's graph kept,
    the mean g(r) of the states every MEMORY_EVERY steps (and the start)
    in the loss, ``backward()`` once at the end."""
    import torch
    f64 = torch.float64
    lengths = torch.tensor(np.diag(atoms.cell.array), dtype=f64)
    n = len(atoms)
    i, j = torch.triu_indices(n, n, 1)
    epsilon = torch.tensor(fit.EPSILON, dtype=f64, requires_grad=True)
    sigma = torch.tensor(STUDENT_SIGMA, dtype=f64, requires_grad=True)
    rc, ro = MEMORY_RC, 0.66 * MEMORY_RC

    def energy(x):
        d = x[j] - x[i]
        d = d - lengths * torch.round(d / lengths)
        r = torch.sqrt((d * d).sum(1))
        s6 = (sigma / r) ** 6
        t = torch.clamp((r - ro) / (rc - ro), 0.0, 1.0)
        switch = 1 - t**3 * (10 - 15 * t + 6 * t * t)
        return (4 * epsilon * (s6 * s6 - s6) * switch).sum()

    def forces(x):
        return -torch.autograd.grad(energy(x), x, create_graph=True)[0]

    h = fit.TIMESTEP
    m = torch.tensor(atoms.get_masses()[:, None], dtype=f64)
    x = torch.tensor(atoms.positions, dtype=f64, requires_grad=True)
    p = torch.tensor(atoms.get_momenta(), dtype=f64)
    f = forces(x)
    total, count = rdf._rdf(x), 1
    for k in range(1, steps + 1):
        p = p + 0.5 * h * f
        x = x + h * p / m
        f = forces(x)
        p = p + 0.5 * h * f
        if k % MEMORY_EVERY == 0 or k == steps:
            total, count = total + rdf._rdf(x), count + 1
    miss = total / count - torch.as_tensor(target_b)
    loss = (miss * miss).sum() * fit.BIN_WIDTH
    loss.backward()
    return float(loss.detach()), {'epsilon': float(epsilon.grad),
                                  'sigma': float(sigma.grad)}


def measure_memory(quick):
    jobs = [(kind, n) for kind, steps in MEMORY_STEPS[quick].items()
            for n in steps]
    jobs.sort(key=lambda job: -job[1])
    raw = dict(zip(jobs, common.run_workers(Path(__file__), jobs)))
    points = {kind: [raw[kind, n] for n in steps]
              for kind, steps in MEMORY_STEPS[quick].items()}
    autograd = points['autograd']
    (n1, r1), (n2, r2) = [(p['steps'], p['max_rss_bytes'])
                          for p in (autograd[0], autograd[-1])]
    per_step = (r2 - r1) / (n2 - n1)
    rev = points['reversible']
    return {'points': points, 'atoms': rev[0]['atoms'],
            'autograd_bytes_per_step': per_step,
            'autograd_extrapolated_bytes': {
                str(p['steps']): r2 + per_step * (p['steps'] - n2)
                for p in rev},
            'reversible_largest_over_smallest':
                rev[-1]['max_rss_bytes'] / rev[0]['max_rss_bytes']}


# -- time ----------------------------------------------------------------------

def measure_time(quick):
    import torch
    torch.set_num_threads(1)
    fit = example()
    from ase_reversible import LennardJones, ReversibleLangevin
    from ase_reversible.core.record import INFO_KEY
    steps, rounds = TIME_STEPS[quick], TIME_ROUNDS[quick]
    cases = []
    students = [('LennardJones (numpy), ε and σ', 4 if not quick else 2,
                 lambda: (LennardJones(epsilon=fit.EPSILON,
                                       sigma=fit.WRONG_SIGMA,
                                       rc=fit.STUDENT_RC),
                          ('epsilon', 'sigma')))]

    def mlp():
        s = fit.MLPStudent(fit.FULL.mlp_cutoff, pretrain_steps=300)
        return s.calc, s.names
    students.append(('PairMLP (torch), every weight', 2, mlp))
    if not quick:
        students.append(('PairMLP (torch), every weight', 4, mlp))
    for label, repeat, make in students:
        atoms = fit.liquid_argon(repeat)
        calc, names = make()
        atoms.calc = calc
        rdf = fit.SmoothRDF(atoms, 5.2 if repeat == 2 else fit.FULL.r_max)
        target_b = rdf.values(atoms.positions)
        dyn = ReversibleLangevin(atoms, fit.TIMESTEP, fit.TEMPERATURE_K,
                                 fit.FRICTION, seed=fit.SEED)
        dyn.run(20)
        atoms.info.pop(INFO_KEY, None)
        forward, backward, exact = [], [], True
        for _ in range(rounds + 1):
            dyn = ReversibleLangevin(atoms, fit.TIMESTEP, fit.TEMPERATURE_K,
                                     fit.FRICTION, seed=fit.SEED)
            x0, p0 = atoms.positions.copy(), atoms.get_momenta()
            t0 = time.perf_counter()
            mean_b, count = fit.sample_rdf(dyn, rdf, steps, fit.FULL.every)
            t1 = time.perf_counter()
            _, dl_b = fit.rdf_loss(mean_b, target_b)
            w_b = dl_b / count
            dyn.backpropagate(
                steps, parameters=names, every=fit.FULL.every,
                window=fit.FULL.window,
                loss=lambda s, k: (rdf.pullback(s.positions, w_b), None))
            t2 = time.perf_counter()
            exact &= (np.array_equal(atoms.positions, x0)
                      and np.array_equal(atoms.get_momenta(), p0))
            forward.append(t1 - t0)
            backward.append(t2 - t1)
            atoms.info.pop(INFO_KEY, None)
        forward, backward = forward[1:], backward[1:]  # the first warms up
        cases.append({
            'student': label, 'atoms': len(atoms), 'steps': steps,
            'parameters': int(sum(np.size(v) for v in
                                  calc.parameter_values(names).values())),
            'forward_seconds_median': statistics.median(forward),
            'gradient_seconds_median': statistics.median(backward),
            'ratio_median': statistics.median(
                b / f for f, b in zip(forward, backward)),
            'exact_return_every_round': bool(exact)})
    return {'cases': cases}


def run(quick=False):
    import os
    return {'gradients': measure_gradients(quick),
            'time': measure_time(quick),
            'memory': measure_memory(quick),
            'load_average_at_end': os.getloadavg()}


if __name__ == '__main__' and sys.argv[1:2] == ['--memory-worker']:
    memory_worker(sys.argv[2], int(sys.argv[3]))
