"""What each section of the docs shows of its stored JSON.

``SPECS[name]`` (in the order of docs/benchmarks.md) is a ``Spec``: the
section's heading, its blocks (each a function of the stored JSON to
Markdown: tables, lists, figure links) and its plots (each writes PNG
files into a folder).  Nothing here measures, judges or imports the
library: the pages can be rebuilt from the JSON alone.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass, field
from typing import Callable


@dataclass(frozen=True)
class Spec:
    """A section: its ``## title`` in docs/benchmarks.md, ``blocks``
    {name: function(stored JSON) -> Markdown}, each filled between its
    markers in whichever docs page holds them, ``plots`` (functions of
    ``results`` and a folder, writing PNG files) and ``values``."""
    title: str
    blocks: dict = field(default_factory=dict)
    plots: tuple[Callable, ...] = ()
    #: Named numbers derived from ``results`` for the pages' inline values
    #: (beside the results' own fields): function(results) -> dict.
    values: Callable = dict


def block(make, *keys):
    """A block: ``make`` of the stored results, or of the part of them
    reached through ``keys``."""
    def markdown(stored):
        part = stored['results']
        for key in keys:
            part = part[key]
        return make(part)
    return markdown


def measured(stored) -> str:
    """The line that says when, how and where a section was measured."""
    machine = stored['machine']
    return (f"*Measured {stored['date']} by `{stored['command']}` in "
            f"{stored['wall_seconds']:.0f} s on {machine['cpu_model']} "
            f"({machine['nproc']} cores), commit {machine['git_commit']}"
            + (', **quick mode: small cases, few repeats**'
               if stored['quick'] else '') + '.*')


def markdown_table(header, rows) -> str:
    """A Markdown table from a header row and rows of cells."""
    lines = ['| ' + ' | '.join(map(str, header)) + ' |',
             '| ' + ' | '.join('---' for _ in header) + ' |']
    lines += ['| ' + ' | '.join(map(str, row)) + ' |' for row in rows]
    return '\n'.join(lines)


def pyplot():
    """matplotlib's pyplot on the non-interactive Agg backend."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    return plt


NAMES = ('step_cost', 'calculators', 'savings', 'work_precision',
         'reversal_error', 'stress', 'gradient_accuracy', 'adjoint',
         'thermostat', 'nose', 'npt_sampling', 'npt_cost', 'lammps_cost',
         'portable', 'force_noise', 'full_precision', 'long_reversal',
         'torch_products', 'training')


def load(name) -> Spec:
    """The spec of section ``name``: its module's ``SPEC``, or its entry
    in ``pages.small``'s ``SPECS`` (the sections that are a table or
    two)."""
    from . import small
    if name in small.SPECS:
        return small.SPECS[name]
    return importlib.import_module(f'pages.{name}').SPEC


SPECS = {name: load(name) for name in NAMES}
