"""What each section of the docs shows of its stored JSON: ``SPECS[name]``
(in the order of docs/benchmarks.md).  Nothing here measures, judges or
imports the library."""

from __future__ import annotations

import importlib
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Callable


@dataclass(frozen=True)
class Spec:
    """A section: its ``## title`` in docs/benchmarks.md, ``blocks``
    {name: function(stored JSON) -> Markdown}, ``plots`` (functions of
    ``results`` and a folder, writing PNG files) and ``values``."""
    title: str
    blocks: dict = field(default_factory=dict)
    plots: tuple[Callable, ...] = ()
    #: Named numbers derived from ``results`` for the pages' inline values
    #: (beside the results' own fields): function(results) -> dict.
    values: Callable = lambda results: {}


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


def table(columns, records) -> str:
    """A Markdown table of ``records`` (dicts): ``columns`` is ((header,
    cell), ...), each cell a ``str.format`` template of the record's
    fields or a function of the record."""
    return markdown_table(
        [header for header, _ in columns],
        [[cell.format(**r) if isinstance(cell, str) else cell(r)
          for _, cell in columns] for r in records])


def pyplot():
    """matplotlib's pyplot on the non-interactive Agg backend."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    return plt


def label(ax, xlabel, ylabel, title, fontsize=10):
    """Name a panel's axes and title it; a legend if it has labels."""
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_title(title, fontsize=fontsize)
    ax.legend(fontsize=8)


@contextmanager
def figure(path, ncols=1, size=(7, 4), dpi=110):
    """(pyplot, figure, axes) of a new figure of ``ncols`` panels, laid
    out and saved to ``path`` (PNG) when the block ends."""
    plt = pyplot()
    fig, axes = plt.subplots(1, ncols, figsize=size)
    yield plt, fig, axes
    fig.tight_layout()
    fig.savefig(path, dpi=dpi)
    plt.close(fig)


NAMES = ('step_cost', 'calculators', 'savings', 'work_precision',
         'reversal_error', 'stress', 'gradient_accuracy', 'adjoint',
         'thermostat', 'nose', 'npt_sampling', 'npt_cost', 'rigid',
         'lammps_cost',
         'portable', 'force_noise', 'full_precision', 'long_reversal',
         'torch_products', 'gpu', 'training')


def load(name) -> Spec:
    """Section ``name``'s spec: ``pages.small``'s or its module's."""
    from . import small
    if name in small.SPECS:
        return small.SPECS[name]
    return importlib.import_module(f'pages.{name}').SPEC


SPECS = {name: load(name) for name in NAMES}
