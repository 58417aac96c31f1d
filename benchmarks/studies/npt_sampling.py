"""ReversibleIsotropicNPT against ASE's IsotropicMTKNPT on the cases of
``systems.NPT_CASES``: volume, compressibility and temperature sampled, and
the reversible run taken back to its start (``--only npt_sampling``:
hours, < 60 s with ``--quick``).
"""

from __future__ import annotations

import common  # noqa: F401  (first: pins BLAS threads before numpy)

import math
import os
import time
import warnings
from dataclasses import asdict, dataclass

import numpy as np
from ase import units
from harness import WINDOW_C, block_mean, integrated_time, warning_lines
from systems import (NPT_AR_CUTOFF, NPT_AR_EPSILON, NPT_AR_REDUCED_DENSITY,
                     NPT_AR_SIGMA, NPT_CASES, NPT_INTEGRATORS, NPT_SEED,
                     PDAMP_NPT_STEPS, TDAMP_NPT_STEPS)

#: Blocks of the jackknife: few and long, as the piston's energy, which
#: sets var(V), decorrelates over thousands of steps.
BLOCKS = 10
#: The goal judged on the page: mean temperature within this of the target.
TEMPERATURE_GOAL_PERCENT = 1.0


@dataclass(frozen=True)
class Lengths:
    equilibration: int
    total: int  # forward steps, equilibration included


FULL = Lengths(equilibration=10_000, total=100_000)
#: The same atoms (256 argon atoms are the fewest asap3 takes), few steps.
QUICK = Lengths(equilibration=100, total=600)


# -- sampling ----------------------------------------------------------------

class Sampler:
    """Observer: volume, kinetic temperature and potential energy after
    every step, indexed by ``dyn.nsteps``; the scaled positions at
    ``marks``, for the mean squared displacement."""

    def __init__(self, dyn, steps, marks):
        self.dyn, self.atoms = dyn, dyn.atoms
        self.volume = np.full(steps + 1, np.nan)
        self.temperature = np.full(steps + 1, np.nan)
        self.potential = np.full(steps + 1, np.nan)
        self.marks = set(marks)
        self.scaled = {}

    def __call__(self):
        i = self.dyn.nsteps
        self.volume[i] = self.atoms.get_volume()
        self.temperature[i] = self.atoms.get_temperature()
        self.potential[i] = self.atoms.get_potential_energy()
        if i in self.marks:
            # Unwrapped: neither integrator wraps positions into the cell.
            self.scaled[i] = np.linalg.solve(self.atoms.cell.T,
                                             self.atoms.positions.T).T

    def mean_squared_displacement(self, start, stop):
        """Of the scaled positions, in Å**2 at the sampled mean cell."""
        length = np.cbrt(np.mean(self.volume[start:stop + 1]))
        d = self.scaled[stop] - self.scaled[start]
        d -= d.mean(axis=0)  # one species: the centre of mass's drift
        return float(length**2 * (d**2).sum(axis=1).mean())


def jackknife_compressibility(volume, kT, blocks=BLOCKS):
    """kappa_T = var(V) / (kT <V>) and its jackknife error over blocks."""
    v = np.asarray(volume, float)
    length = len(v) // blocks
    v = v[:length * blocks]
    kappa = float(v.var() / (kT * v.mean()))
    parts = v.reshape(blocks, length)
    leave_one_out = np.empty(blocks)
    for k in range(blocks):
        rest = np.delete(parts, k, axis=0).ravel()
        leave_one_out[k] = rest.var() / (kT * rest.mean())
    error = math.sqrt((blocks - 1) / blocks
                      * ((leave_one_out - leave_one_out.mean())**2).sum())
    # (V - <V>)**2 follows the piston's slow energy, so its correlations
    # outlast V's: its autocorrelation time gives a second error.
    square = (v - v.mean())**2
    g = integrated_time(square)
    error_g = kappa * math.sqrt(g * square.var() / len(v)) / square.mean()
    return {'value_A3_per_eV': kappa, 'standard_error_A3_per_eV': error,
            'per_GPa': kappa * units.GPa,
            'standard_error_per_GPa': error * units.GPa,
            'square_correlation_time_steps': g,
            'standard_error_from_g_per_GPa': error_g * units.GPa}


def statistics_of(sampler, first, case):
    volume = sampler.volume[first:]
    temperature = sampler.temperature[first:]
    if not (np.all(np.isfinite(volume)) and np.all(np.isfinite(temperature))):
        raise RuntimeError('a sampled step is missing: the observer did not '
                           'run after every step')
    kT = units.kB * case.temperature_K
    v = block_mean(volume)
    g = integrated_time(volume)
    start, half, last = sorted(sampler.marks)
    return {
        'samples': len(volume),
        'volume_A3': {**v, 'correlation_time_steps': g,
                      'block_length_over_correlation_time':
                          v['block_length'] / g},
        'compressibility': jackknife_compressibility(volume, kT),
        'temperature_K': {**block_mean(temperature),
                          'correlation_time_steps':
                              integrated_time(temperature)},
        'potential_energy_eV': block_mean(sampler.potential[first:]),
        'msd_A2': {'half': sampler.mean_squared_displacement(start, half),
                   'end': sampler.mean_squared_displacement(start, last),
                   'half_steps': half - start, 'end_steps': last - start},
    }


def exact_state(dyn):
    """Every exact variable's integers and the atoms' floats."""
    atoms = dyn.atoms
    return {'engine': dyn.engine.snapshot(),
            'positions': atoms.get_positions(),
            'momenta': atoms.get_momenta(),
            'cell': atoms.cell.array.copy()}


def compare(start, end):
    """``{what: array_equal}`` of two exact_state's."""
    equal = {f'variable {name}': bool(np.array_equal(
        start['engine'][name], end['engine'].get(name)))
        for name in start['engine']}
    for key in ('positions', 'momenta', 'cell'):
        equal[key] = bool(np.array_equal(start[key], end[key]))
    return equal


def buffers(dyn):
    """The thermostat's information buffers (none for ASE's)."""
    step = getattr(dyn, 'friction_step', None)
    return list(step.buffers.values()) if step is not None else []


def buffer_bits(dyn):
    return int(sum(b.bits for b in buffers(dyn)))


def run_one(case, name, lengths, repeat=None, round_trip=False):
    """One integrator's sampling run (and, with ``round_trip``, the way
    back); returns (sampler, record)."""
    label, atoms = case.atoms(repeat)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter('always')
        dyn = NPT_INTEGRATORS[name](atoms, case)
        start = exact_state(dyn) if round_trip else None
        half = lengths.equilibration + (lengths.total
                                        - lengths.equilibration) // 2
        sampler = Sampler(dyn, lengths.total,
                          (lengths.equilibration, half, lengths.total))
        dyn.attach(sampler, interval=1)
        tic = time.perf_counter()
        dyn.run(lengths.total)
        record = {'calculator': label,
                  'forward_seconds': time.perf_counter() - tic}
        if round_trip:
            moved = not np.array_equal(atoms.get_positions(),
                                       start['positions'])
            cell_moved = not np.array_equal(atoms.cell.array, start['cell'])
            dyn.observers.clear()  # the way back is a plain run
            bits_at_turn = buffer_bits(dyn)
            dyn.reverse()
            tic = time.perf_counter()
            dyn.run(lengths.total)
            back = time.perf_counter() - tic
            equal = compare(start, exact_state(dyn))
            equal['buffers empty'] = all(b.is_empty() for b in buffers(dyn))
            record['round_trip'] = {
                'steps_each_way': lengths.total, 'moved': moved,
                'cell_moved': cell_moved, 'equal': equal,
                'buffer_bits_at_turn': bits_at_turn,
                'buffer_bits_after': buffer_bits(dyn),
                'back_seconds': back}
    record['warnings'] = warning_lines(caught)
    return sampler, record


def compressibility_error(kappa):
    """The larger of kappa_T's two errors (blocks, autocorrelation), /GPa."""
    return max(kappa['standard_error_per_GPa'],
               kappa['standard_error_from_g_per_GPa'])


def difference(a, b):
    se = math.hypot(a[1], b[1])
    return {'difference': a[0] - b[0], 'combined_error': se,
            'in_errors': (a[0] - b[0]) / se if se > 0 else float('nan')}


def compared(ours, theirs):
    """The reversible run's numbers minus ASE's, in combined errors."""
    def pair(get):
        return difference(get(ours), get(theirs))
    return {
        'volume': pair(lambda s: (s['volume_A3']['mean'],
                                  s['volume_A3']['standard_error'])),
        'compressibility': pair(lambda s: (
            s['compressibility']['per_GPa'],
            compressibility_error(s['compressibility']))),
        'temperature': pair(lambda s: (s['temperature_K']['mean'],
                                       s['temperature_K']['standard_error'])),
        'potential_energy': pair(lambda s: (
            s['potential_energy_eV']['mean'],
            s['potential_energy_eV']['standard_error'])),
    }


def sampling_case(case, lengths, repeat=None, names=tuple(NPT_INTEGRATORS)):
    """Both integrators on one case."""
    first = lengths.equilibration + 1
    runs, samplers = {}, {}
    for name in names:
        sampler, record = run_one(
            case, name, lengths, repeat,
            round_trip=case.round_trip and name == 'reversible_npt')
        n_atoms = len(sampler.atoms)
        record.update(statistics_of(sampler, first, case))
        runs[name], samplers[name] = record, sampler
    result = {**asdict(case), 'n_atoms': n_atoms,
              'calculator': runs[names[-1]]['calculator'],
              'equilibration_steps': lengths.equilibration,
              'total_steps': lengths.total, 'runs': runs}
    result['difference'] = compared(runs['reversible_npt'], runs['ase_npt'])
    line = '  '.join(
        f"{k}: V {r['volume_A3']['mean']:.1f}±"
        f"{r['volume_A3']['standard_error']:.1f} "
        f"kappa {r['compressibility']['per_GPa']:.4g}±"
        f"{compressibility_error(r['compressibility']):.2g}/GPa "
        f"T {r['temperature_K']['mean']:.2f}" for k, r in runs.items())
    print(f'  {case.label}: {line}', flush=True)
    return result


def run(quick, cases=NPT_CASES):
    lengths = QUICK if quick else FULL
    load = {'start': os.getloadavg()}
    results = [sampling_case(c, lengths) for c in cases]
    load['end'] = os.getloadavg()
    return {'load_average': load,
            'settings': {'seed': NPT_SEED, 'blocks': BLOCKS, 'window_c': WINDOW_C,
                         'tdamp_steps': TDAMP_NPT_STEPS,
                         'pdamp_steps': PDAMP_NPT_STEPS,
                         'temperature_goal_percent': TEMPERATURE_GOAL_PERCENT,
                         'argon': {'epsilon_eV': NPT_AR_EPSILON,
                                   'sigma_A': NPT_AR_SIGMA,
                                   'cutoff_A': NPT_AR_CUTOFF,
                                   'start_reduced_density':
                                       NPT_AR_REDUCED_DENSITY},
                         **{f'lengths_{k}': v
                            for k, v in asdict(lengths).items()}},
            'cases': results}

