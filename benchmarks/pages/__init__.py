"""The sections of docs/benchmarks.md, each rendered from its stored JSON.

One module per section, named like its measurement script, with ``TITLE``,
``markdown(results) -> str`` and ``plot(results, figures)`` (writes the
section's PNG files into ``figures``).  Nothing here measures or imports
the library: a page can be rebuilt from the JSON alone.
"""

from __future__ import annotations


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
