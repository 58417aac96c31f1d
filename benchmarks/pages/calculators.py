"""Calculators (benchmarks/calculators.py)."""

from __future__ import annotations

import math
import re

from . import Spec, markdown_table

#: Above this many force calls, a repeated get_forces() is a recomputation
#: rather than a cache hit (these differ a hundredfold).
REPEAT_RECOMPUTES = 0.5


def _exponent(power_of_two):
    """``k`` of ``2**k``, or None for a quantum that is no power of two."""
    mantissa, exponent = math.frexp(power_of_two)
    return exponent - 1 if mantissa == 0.5 else None


def quantum(q):
    k = _exponent(q)
    return f'2^{k}' if k is not None else f'{q:.3g}'


def refusal(message):
    """The size of the noise an ImpureForcesError names, as a short cell."""
    found = re.search(r'differ by (\S+) eV/Å', message)
    return (f'refused: history noise {found.group(1)} eV/Å' if found
            else 'refused: ' + message.split('. ')[0])


def auto_text(auto):
    if auto.get('mode'):
        return f"'{auto['mode']}'"
    if 'refused' in auto:
        return refusal(auto['refused'])
    return f"error: {auto['error']}"


def auto_cell(r):
    return auto_text(r['auto'])


def exact_cell(r):
    rev = r['reversal']
    verdict = 'yes' if rev['exact'] else (
        f"no (missed by {rev['position_miss_quanta']} position, "
        f"{rev['momentum_miss_quanta']} momentum quanta)")
    run = '' if r['mode_run'] == r['auto'].get('mode') else \
        f" ('{r['mode_run']}')"
    return f"{verdict}{run}, {rev['steps']} + {rev['steps']} steps"


def cost_cell(r):
    cost = r['cost']
    per_round = [a / b for a, b in zip(cost['per_step_seconds']['rv'],
                                       cost['per_step_seconds']['vv'])]
    cpu = cost['median_cpu_seconds']
    return (f"×{cost['ratio']:.2f} ({1e3 * cost['median_seconds']['rv']:.3g}"
            f" / {1e3 * cost['median_seconds']['vv']:.3g} ms; rounds "
            f'×{min(per_round):.2f}–{max(per_round):.2f}; CPU time '
            f"×{cpu['rv'] / cpu['vv']:.2f})")


def notes(r):
    out = [r['setup']] if r.get('setup') else []
    rev = r.get('reversal')
    if rev and rev['clean_recomputations'] is not None:
        out.append(f"{rev['clean_recomputations']} clean recomputations in "
                   f"{2 * rev['steps']} steps")
    if rev and not rev['moved']:
        out.append('the atoms did not move: the run proves nothing')
    for w in (rev or {}).get('warnings', []):
        out.append(f'warned: {w}')
    again = (r.get('cost') or {}).get('repeated_call_in_force_calls')
    if again is not None and again > REPEAT_RECOMPUTES:
        out.append(f'get_forces() asked again at unchanged positions costs '
                   f'{again:.2f} force calls (VelocityVerlet asks in every '
                   f'step)')
    if r.get('omp_num_threads') is not None:
        out.append(f"OMP_NUM_THREADS={r['omp_num_threads']}")
    return '; '.join(out)


def row_cells(r):
    name = r['label'] + (f" {r['version']}" if r.get('version') else '')
    if 'skipped' in r:
        return (name, r['system'] or '—', '—', '—', '—', '—',
                f"not run: {r['skipped']}")
    system = f"{r['system']}, {r['n_atoms']} atoms, {r['timestep_fs']:g} fs"
    if 'reversal' not in r or 'cost' not in r:
        failed = (f"run with '{r['mode_run']}' failed: {r['run_error']}"
                  if 'run_error' in r else '')
        return (name, system, auto_cell(r), '—', '—', '—',
                '; '.join(filter(None, (notes(r), failed))))
    return (name, system, auto_cell(r), exact_cell(r),
            quantum(r['reversal']['grid']['momentum_quantum']), cost_cell(r),
            notes(r))


SPEC = Spec('Calculators', blocks={
    'table': lambda stored: markdown_table(
        ('calculator', 'system', "force_purity='auto'", 'exact',
         'momentum quantum', 'per step / VelocityVerlet', 'notes'),
        [row_cells(r) for r in stored['results']['rows']])})
