"""How the benchmark scripts measure: time per step in interleaved rounds,
memory, the statistics of sampled series (import ``common`` first)."""

from __future__ import annotations

import math
import resource
import statistics
import sys
import time
import warnings
from dataclasses import dataclass

import numpy as np
from ase import units
from scipy import stats

#: Move of one coordinate (Å) that makes a calculator recompute: far below
#: any neighbour-list skin, so it never triggers a rebuild.
FLOOR_NUDGE = 1e-6
#: Blocks of the block averages.
BLOCKS = 20
#: Sokal's window: sum the autocorrelation up to the first m >= C g(m).
WINDOW_C = 5.0
#: Steps between readings of sum F**2 / m (for the mean squared frequency).
FORCE_EVERY = 10
#: Bins of the kinetic-energy histograms.
HISTOGRAM_BINS = 40


# -- time per step ------------------------------------------------------------

@dataclass(frozen=True)
class Settings:
    rounds: int
    block_seconds: float  # target wall time of one block of the reference
    min_steps: int        # per block, however slow the case
    max_steps: int
    warmup_steps: int


@dataclass
class Contestant:
    name: str
    runner: object  # anything with run(steps)

    @property
    def purity(self):
        """The ReversibleVerlet force provider, or None."""
        return getattr(self.runner, 'force_purity', None)

    def clean_recomputations(self):
        return getattr(self.purity, 'clean_recomputations', None)


def choose_steps(run, settings, resolution=10):
    """Steps per block so that ``run(steps)`` takes about
    ``settings.block_seconds`` (steps doubled from 1 until a sample lasts a
    ``resolution``-th of that)."""
    steps = 1
    while True:
        t0 = time.perf_counter()
        run(steps)
        elapsed = time.perf_counter() - t0
        if (elapsed > settings.block_seconds / resolution
                or steps >= settings.max_steps):
            break
        steps *= 2
    wanted = round(settings.block_seconds * steps / elapsed)
    return max(settings.min_steps, min(settings.max_steps, wanted))


def time_interleaved(contestants, steps, rounds):
    """Seconds per step of each contestant, the order rotated each round so
    that the machine's drifts hit all alike: ``(wall, cpu)``, each ``{name:
    [one value per round]}`` (CPU time shows what other processes took)."""
    wall, cpu = ({c.name: [] for c in contestants} for _ in range(2))
    for r in range(rounds):
        shift = r % len(contestants)
        for c in contestants[shift:] + contestants[:shift]:
            w0, c0 = time.perf_counter(), time.process_time()
            c.runner.run(steps)
            wall[c.name].append((time.perf_counter() - w0) / steps)
            cpu[c.name].append((time.process_time() - c0) / steps)
    return wall, cpu


def medians(samples):
    return {k: statistics.median(v) for k, v in samples.items()}


def per_step(wall, cpu):
    """``time_interleaved``'s samples stored: raw, medians, and the spread
    (max - min) / median of each contestant."""
    return {'per_step_seconds': wall, 'per_step_cpu_seconds': cpu,
            'median_seconds': medians(wall),
            'median_cpu_seconds': medians(cpu),
            'spread': {k: (max(v) - min(v)) / statistics.median(v)
                       for k, v in wall.items()}}


def time_cached_queries(atoms, calls, rounds=3):
    """Median seconds per call of ``get_forces()`` asked again at unchanged
    positions, and of ``get_potential_energy()`` right after a force
    calculation (ASE's integrators and loggers ask both every step)."""
    forces_again, energy_after = [], []
    x_nc = atoms.arrays['positions']
    for _ in range(rounds):
        atoms.get_forces(md=True)
        t0 = time.perf_counter()
        for _ in range(calls):
            atoms.get_forces(md=True)
        forces_again.append((time.perf_counter() - t0) / calls)
        elapsed = 0.0
        for i in range(calls):
            x_nc[0, 0] += FLOOR_NUDGE if i % 2 == 0 else -FLOOR_NUDGE
            atoms.get_forces(md=True)
            t0 = time.perf_counter()
            atoms.get_potential_energy()
            elapsed += time.perf_counter() - t0
        energy_after.append(elapsed / calls)
    return statistics.median(forces_again), statistics.median(energy_after)


def speed_case(system, repeat, settings, names, integrators, reference):
    """Interleaved per-step times of the integrators ``names`` (keys of
    ``integrators``, each ``(atoms, system) -> dynamics``) on
    ``system.atoms(repeat)``, blocks sized on ``reference``."""
    template = system.atoms(repeat)
    contestants = []
    for name in names:
        atoms = template.copy()
        atoms.calc = system.calculator_instance()
        contestants.append(Contestant(name, integrators[name](atoms, system)))
    for c in contestants:
        c.runner.run(settings.warmup_steps)
    by_name = {c.name: c for c in contestants}
    steps = choose_steps(by_name[reference].runner.run, settings)
    wall, cpu = time_interleaved(contestants, steps, settings.rounds)
    result = {'system': system.label, 'calculator': system.calculator,
              'n_atoms': len(template), 'timestep_fs': system.timestep_fs,
              'temperature_K': system.temperature_K,
              'steps_per_block': steps, 'rounds': settings.rounds,
              **per_step(wall, cpu)}
    print(f'  {system.calculator:10s} N={len(template):5d} S={steps:4d}  '
          + '  '.join(f'{k}={v * 1e6:.0f}µs'
                      for k, v in result['median_seconds'].items()),
          flush=True)
    return result


# -- memory -------------------------------------------------------------------

def max_rss_bytes():
    """The process's peak resident set size so far."""
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return rss if sys.platform == 'darwin' else rss * 1024  # Linux: KiB


def resident_bytes():
    """The process's resident set size now (Linux), or None."""
    try:
        with open('/proc/self/statm') as f:
            return int(f.read().split()[1]) * resource.getpagesize()
    except (OSError, ValueError, IndexError):
        return None


# -- statistics of a sampled series -------------------------------------------

def integrated_time(x, window_c=WINDOW_C):
    """Integrated autocorrelation time ``g = 1 + 2 sum_t rho(t)`` (samples),
    summed up to the first lag ``m >= window_c g(m)``."""
    x = np.asarray(x, float) - np.mean(x)
    n = len(x)
    f = np.fft.rfft(x, 2 * n)
    acf = np.fft.irfft(f * np.conj(f))[:n]
    acf /= acf[0]
    g = 2.0 * np.cumsum(acf) - 1.0
    window = np.arange(n) >= window_c * g
    m = int(np.argmax(window)) if window.any() else n - 1
    return float(g[m])


def block_mean(x, blocks=BLOCKS):
    """Mean and its standard error from ``blocks`` block averages."""
    x = np.asarray(x, float)
    length = len(x) // blocks
    means = x[:length * blocks].reshape(blocks, length).mean(axis=1)
    return {'mean': float(x.mean()),
            'standard_error': float(means.std(ddof=1) / math.sqrt(blocks)),
            'blocks': blocks, 'block_length': length}


@dataclass(frozen=True)
class StudyLengths:
    """Steps of a sampled run: ``equilibration`` steps, then ``sampled``."""
    equilibration: int
    sampled: int


class KineticSampler:
    """Observer: internal kinetic and potential energy every step, sum F**2
    / m every ``FORCE_EVERY`` steps, indexed by ``dyn.nsteps``; arrays of
    ``steps + 1`` (eV, eV, eV/Å**2/amu)."""

    def __init__(self, dyn, steps):
        self.dyn, self.atoms = dyn, dyn.atoms
        self.kinetic = np.full(steps + 1, np.nan)
        self.potential = np.full(steps + 1, np.nan)
        self.com_kinetic = np.full(steps + 1, np.nan)
        self.force_square = np.full(steps + 1, np.nan)
        self.total_mass = float(self.atoms.get_masses().sum())

    def __call__(self):
        i = self.dyn.nsteps
        p_nc = self.atoms.get_momenta()
        p_c = p_nc.sum(axis=0)
        k = 0.5 * float((p_nc**2 / self.atoms.get_masses()[:, None]).sum())
        self.com_kinetic[i] = 0.5 * float(p_c @ p_c) / self.total_mass
        self.kinetic[i] = k - self.com_kinetic[i]
        self.potential[i] = self.atoms.get_potential_energy()
        if i % FORCE_EVERY == 0:
            f_nc = self.atoms.get_forces()
            self.force_square[i] = float(
                (f_nc**2 / self.atoms.get_masses()[:, None]).sum())


def histogram_edges(dof, kT):
    """``HISTOGRAM_BINS + 1`` edges (eV), equal widths over the central
    99.9% of Gamma(dof / 2, kT)."""
    ends = stats.gamma.ppf([0.0005, 0.9995], dof / 2, scale=kT)
    return np.linspace(ends[0], ends[1], HISTOGRAM_BINS + 1)


def canonical_statistics(sampler, first, dof, kT, edges, timestep):
    """A ``KineticSampler``'s steps from ``first`` on against the canonical
    distribution: temperature, potential energy, correlation times, and
    Kolmogorov-Smirnov of the kinetic energy against Gamma(dof / 2, kT)
    thinned to every ``ceil(2 g)``-th step."""
    kinetic = sampler.kinetic[first:]
    potential = sampler.potential[first:]
    assert np.all(np.isfinite(kinetic)) and np.all(np.isfinite(potential))
    g = integrated_time(kinetic)
    stride = math.ceil(2 * g)
    thinned = kinetic[::stride]
    d = np.asarray(thinned, float) - np.mean(thinned)  # for the lag-1 corr.
    ks = stats.kstest(thinned, 'gamma', args=(dof / 2, 0.0, kT))
    # The shape alone: the scale from the measured mean kinetic energy.
    ks_shape = stats.kstest(thinned, 'gamma',
                            args=(dof / 2, 0.0, 2 * kinetic.mean() / dof))
    counts, _ = np.histogram(kinetic, edges)
    # <F_i**2> = kT <d2U/dx_i**2>: the mean of the mass-weighted Hessian's
    # trace; BAOAB's full-step <p**2> = m kT (1 - h**2 omega**2 / 4).
    omega2 = float(np.nanmean(sampler.force_square[first:]) / (kT * dof))
    return {
        'mean_omega_squared_per_fs2': omega2 * units.fs**2,
        'baoab_harmonic_kinetic_bias_percent':
            -100 * timestep**2 * omega2 / 4,
        'samples': len(kinetic),
        'temperature_K': block_mean(2 * kinetic / (dof * units.kB)),
        'potential_energy': {**block_mean(potential),
                             'correlation_time_steps':
                                 integrated_time(potential)},
        'kinetic_correlation_time_steps': g,
        'ks': {'stride': stride, 'samples': len(thinned),
               'lag1_of_thinned': float((d[1:] @ d[:-1]) / (d @ d)),
               'statistic': float(ks.statistic),
               'p_value': float(ks.pvalue),
               'shape_p_value': float(ks_shape.pvalue)},
        'max_com_kinetic_over_kT': float(np.max(sampler.com_kinetic[first:])
                                         / kT),
        'histogram_counts': counts.tolist(),
    }


def against_reference(system, first, ours, reference, make, steps):
    """``ours``, a (name, KineticSampler) pair, against ASE's thermostat
    ``make(atoms, system)`` run ``steps`` steps from the same atoms: both
    ``canonical_statistics`` from step ``first`` on, and the potential
    energies' difference."""
    dyn = make(system.atoms(), system)
    theirs = KineticSampler(dyn, steps)
    dyn.attach(theirs, interval=1)
    tic = time.perf_counter()
    dyn.run(steps)
    seconds = time.perf_counter() - tic
    n_atoms = len(theirs.atoms)
    dof = 3 * n_atoms - 3
    kT = units.kB * system.temperature_K
    edges = histogram_edges(dof, kT)
    h = system.timestep_fs * units.fs
    sampled = {name: canonical_statistics(sampler, first, dof, kT, edges, h)
               for name, sampler in (ours, (reference, theirs))}
    sampled[reference]['seconds'] = seconds
    a, b = sampled[ours[0]], sampled[reference]
    print(f"  {system.label:9s} N={n_atoms}  T_kin "
          f"{a['temperature_K']['mean']:.2f} / {b['temperature_K']['mean']:.2f}"
          f" K  KS p {a['ks']['p_value']:.2g} / {b['ks']['p_value']:.2g}",
          flush=True)
    return {'system': system.label, 'calculator': system.calculator,
            'n_atoms': n_atoms, 'dof': dof,
            'temperature_K': system.temperature_K,
            'timestep_fs': system.timestep_fs, 'kT_eV': kT,
            'histogram_edges_eV': edges.tolist(), 'sampling': sampled,
            'potential_difference_eV':
                a['potential_energy']['mean'] - b['potential_energy']['mean'],
            'potential_difference_standard_error_eV': math.hypot(
                a['potential_energy']['standard_error'],
                b['potential_energy']['standard_error'])}


def warning_lines(caught):
    """The distinct warnings of a ``catch_warnings(record=True)`` list."""
    return sorted({f'{w.category.__name__}: {w.message}' for w in caught})


class NoseSampler(KineticSampler):
    """``KineticSampler`` with Nosé's ``s`` every step and the extended
    energy every ``FORCE_EVERY`` steps."""

    def __init__(self, dyn, steps):
        super().__init__(dyn, steps)
        self.s = np.full(steps + 1, np.nan)
        self.extended = np.full(steps + 1, np.nan)

    def __call__(self):
        super().__call__()
        i = self.dyn.nsteps
        self.s[i] = self.dyn.thermostat_position
        if i % FORCE_EVERY == 0:
            self.extended[i] = self.dyn.get_conserved_energy()


def nose_statistics(sampler, first, timestep_fs):
    """A ``NoseSampler``'s ``s``, real time step ``dt / s`` (fs) and extended
    energy (eV), from step ``first`` on."""
    s_all = sampler.s
    s = s_all[first:]
    extended = sampler.extended[np.isfinite(sampler.extended)]
    return {
        's': {**block_mean(s), 'std': float(s.std()),
              'min': float(s.min()), 'max': float(s.max()),
              'correlation_time_steps': integrated_time(s)},
        's_from_start': {'min': float(s_all.min()), 'max': float(s_all.max()),
                         'first': float(s_all[0])},
        'real_timestep_fs': {'mean': float(np.mean(timestep_fs / s)),
                             'min': float(timestep_fs / s.max()),
                             'max': float(timestep_fs / s.min()),
                             'rms': timestep_fs * math.sqrt(
                                 float(np.mean(1.0 / s**2)))},
        'extended_energy_eV': {
            'first': float(extended[0]), 'last': float(extended[-1]),
            'max_deviation': float(np.max(np.abs(extended - extended[0]))),
            'std': float(extended.std())},
    }


def there_and_back(make, sampler_class, steps, checkpoints=(),
                   at_checkpoint=None, at_turn=None, snapshot=None):
    """``make()``'s dynamics ``steps`` steps out with a ``sampler_class(dyn,
    steps)`` observing (``at_checkpoint(dyn, step)`` at ``checkpoints``,
    ``at_turn(dyn)``, a dict, at the end), then reversed and as many steps
    back unobserved, warnings recorded: ``(dyn, sampler, record)``, the
    record's 'start' being ``snapshot(dyn)`` before the first step."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter('always')
        dyn = make()
        start = snapshot(dyn) if snapshot else None
        atoms = dyn.atoms
        x0_nc, p0_nc = atoms.get_positions(), atoms.get_momenta()
        sampler = sampler_class(dyn, steps)
        dyn.attach(sampler, interval=1)
        points, done = [], 0
        tic = time.perf_counter()
        for stop in sorted(set(checkpoints) | {steps}):
            dyn.run(stop - done)
            done = stop
            if stop in checkpoints:
                points.append(at_checkpoint(dyn, stop))
        forward = time.perf_counter() - tic
        record = {'start': start,
                  'moved': not np.array_equal(atoms.get_positions(), x0_nc),
                  **(at_turn(dyn) if at_turn else {})}
        dyn.observers.clear()  # the way back is a plain run
        dyn.reverse()
        tic = time.perf_counter()
        dyn.run(steps)
    record.update(
        forward_seconds=forward, back_seconds=time.perf_counter() - tic,
        checkpoints=points, warnings=warning_lines(caught),
        positions_equal=bool(np.array_equal(atoms.get_positions(), x0_nc)),
        momenta_equal=bool(np.array_equal(atoms.get_momenta(), p0_nc)))
    return dyn, sampler, record
