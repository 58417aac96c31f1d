"""Long exact round trips with ASE's LennardJones.

Measured by benchmarks/long_reversal.py.
"""

from __future__ import annotations

from . import markdown_table

TITLE = 'Long round trips with ASE LennardJones'


def plot(results, figures):
    """No plot: one table."""


def markdown(results):
    rows = [[r['scheme'], f"{r['steps']:,}", 'yes' if r['exact'] else '**no**',
             f"{r['largest_displacement_at_turn']:.2f}",
             f"{r['seconds']:.0f}"] for r in results['runs']]
    return (
        f"Ar{results['atoms']} at {results['temperature_K']:g} K, ASE "
        f"LennardJones, {results['timestep_fs']:g} fs: N steps forward, "
        'reverse, N steps back, and `np.array_equal` of positions and '
        'momenta with the start (`benchmarks/long_reversal.py`).\n\n'
        + markdown_table(['scheme', 'N each way', 'back at start bit for bit',
                          'largest displacement at the turn (Å)',
                          'wall time (s)'], rows))
