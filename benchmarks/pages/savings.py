"""Savings on the per-step path: the package at several commits side by side.

Measured by benchmarks/savings.py.
"""

from __future__ import annotations

from . import markdown_table

TITLE = 'Savings on the per-step path'


def plot(results, figures):
    """No plot: the table says it all."""


def markdown(results):
    if not results['cases']:
        return ('Skipped: the baseline commits '
                f"{', '.join(results['skipped'])} are not in this clone.")
    commits = [c['commit'] for c in results['commits']
               if c['commit'] not in results['skipped']]
    reference = 'VelocityVerlet'
    # CPU time where it was measured: on a shared machine it leaves out the
    # waits for a core that blur the wall-clock medians.
    def per_step(case):
        return case.get('cpu_ms_per_step', case['ms_per_step'])

    versus = [[case['case']] + [
        f"{per_step(case)[c] / per_step(case)[reference]:.3f}"
        for c in commits] for case in results['cases']
        if reference in case['ms_per_step']]
    rows = []
    for case in results['cases']:
        base = case['ms_per_step'][commits[0]]
        rows.append([case['case']] + [
            f"{case['ms_per_step'][c]:.3f} ({case['ms_per_step'][c] / base:.3f})"
            for c in commits] + [f"{case['spread']:.0%}"])
    changes = '\n'.join(f"- `{c['commit']}`: {c['change']}"
                        for c in results['commits'])
    return f"""The package at each commit below runs in a worker process of its own
on the same system; blocks of steps are interleaved between the workers in
rotating order and the medians compared (`benchmarks/savings.py`).
Default settings (`scheme='velocity'`, `force_purity='auto'`, 5 fs).

{changes}

ms per step (ratio to the first commit):

{markdown_table(['case'] + commits + ['round spread'], rows)}
""" + (f"""
Ratio to ASE's VelocityVerlet, run by a worker of its own in the same
rounds (medians of the workers' CPU time per step):

{markdown_table(['case'] + commits, versus)}
""" if versus else '')
