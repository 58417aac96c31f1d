"""Fill the generated blocks of the docs pages from the stored results.

    python benchmarks/render.py            # docs/ from docs/benchmarks/*.json
    python benchmarks/render.py --check    # exit 1, with a diff, if stale
    python benchmarks/render.py --out DIR  # DIR/*.md from DIR/benchmarks/

The prose of the docs pages is written by hand; the numbers are not.  They
sit between marker comments (``block_markers``) naming a section (its
``<out>/benchmarks/<section>.json``) and one of its blocks
(``pages.SPECS``), each declared block found once, or inline in the prose
(``INLINE``).  The renderer formats, it does not judge or measure.
"""

from __future__ import annotations

import argparse
import difflib
import json
import re
import shutil
import sys
from pathlib import Path

from pages import SPECS, measured

ROOT = Path(__file__).resolve().parent.parent
DOCS = ROOT / 'docs'

#: The sections in the order of docs/benchmarks.md.
SECTIONS = tuple(SPECS)

MARKER = re.compile(r'<!-- (\w+) ([\w-]+): written by benchmarks/render\.py')
#: A number in the prose: ``<!--=section {field:format}-->value<!---->``,
#: the field a ``str.format`` one of the section's results (or of its
#: spec's ``values``); the value after it is rewritten.
INLINE = re.compile(r'<!--=(\w+) (.*?)-->(.*?)<!---->')


def block_markers(name, block):
    """The lines that open and close a generated block of a page."""
    return (f'<!-- {name} {block}: written by benchmarks/render.py from '
            f'docs/benchmarks/{name}.json; edits are overwritten -->',
            f'<!-- end of {name} {block} -->')


def with_blocks(text, name, blocks) -> str:
    """``text`` with each block's markers enclosing its new Markdown; missing
    markers are an error, so a moved heading cannot leave old numbers."""
    for block, markdown in blocks.items():
        begin, end = block_markers(name, block)
        if text.count(begin) != 1 or text.count(end) != 1:
            raise ValueError(f'expected the markers of {name} {block} once '
                             f'each: {begin} ... {end}')
        head, rest = text.split(begin)
        _, tail = rest.split(end)
        text = f'{head}{begin}\n\n{markdown.strip()}\n\n{end}{tail}'
    return text


def stored_sections(out: Path) -> dict:
    """{name: stored JSON} of the sections measured into ``out``."""
    found = {}
    for name in SECTIONS:
        path = out / 'benchmarks' / f'{name}.json'
        if path.exists():
            found[name] = json.loads(path.read_text())
    return found


def block_markdown(name, block, stored) -> str:
    """One block's Markdown from the section's stored JSON."""
    if name not in stored:
        return (f'*Not measured yet: `python benchmarks/run_all.py --only '
                f'{name}` stores benchmarks/{name}.json.*'
                if block == 'measured' else '')
    if block == 'measured':
        return measured(stored[name])
    return SPECS[name].blocks[block](stored[name])


def inline_values(text, stored) -> str:
    """``text`` with every inline value rewritten from ``stored``."""
    def value(match):
        name, template = match[1], match[2]
        if name not in stored:
            return f'<!--={name} {template}-->?<!---->'
        results = stored[name]['results']
        try:
            text = template.format(**{**results,
                                      **SPECS[name].values(results)})
        except (KeyError, IndexError, TypeError, ValueError):
            # A run that measured less (quick mode, an older JSON).
            text = '(not measured)'
        return f'<!--={name} {template}-->{text}<!---->'
    return INLINE.sub(value, text)


def rendered_pages(out: Path) -> dict:
    """{page: (old text, new text)} of the pages of ``out`` with generated
    blocks; raises if a block is unknown, missing or repeated."""
    stored = stored_sections(out)
    pages, seen = {}, {}
    for path in sorted(out.glob('*.md')):
        text = path.read_text()
        found = MARKER.findall(text)
        for name, block in found:
            if name not in SPECS or (block != 'measured'
                                     and block not in SPECS[name].blocks):
                raise ValueError(f'{path.name}: no block {name} {block}')
            seen.setdefault((name, block), []).append(path.name)
        new = inline_values(text, stored)
        for name, block in found:
            new = with_blocks(new, name, {
                block: block_markdown(name, block, stored)})
        if new != text or found:
            pages[path] = (text, new)
    for name, spec in SPECS.items():
        for block in ('measured', *spec.blocks):
            where = seen.get((name, block), [])
            if len(where) != 1:
                raise ValueError(f'block {name} {block} is in '
                                 f'{where or "no page"}, expected once')
        if f'\n## {spec.title}\n' not in (out / 'benchmarks.md').read_text():
            raise ValueError(f'benchmarks.md has no heading ## {spec.title}')
    return pages


def render(out: Path, plots=True) -> Path:
    """Rewrite the generated blocks of the pages in ``out`` (and, with
    ``plots``, every plot of a stored section); a directory other than
    docs/ gets a copy of each docs page with generated blocks to fill."""
    for source in DOCS.glob('*.md'):
        if not (out / source.name).exists() and MARKER.search(
                source.read_text()):
            shutil.copy(source, out / source.name)
    if plots:
        for name, s in stored_sections(out).items():
            for plot in SPECS[name].plots:
                plot(s['results'], out / 'benchmarks')
    for path, (_, new) in rendered_pages(out).items():
        path.write_text(new)
    return out / 'benchmarks.md'


def check(out: Path) -> int:
    """0 when the generated blocks of ``out`` are what the stored JSON
    renders to; else 1, with the diff on stdout."""
    stale = 0
    for path, (old, new) in rendered_pages(out).items():
        if old != new:
            stale = 1
            sys.stdout.writelines(difflib.unified_diff(
                old.splitlines(True), new.splitlines(True),
                f'{path.name} (committed)', f'{path.name} (rendered)'))
    if stale:
        print('\nstale: run python benchmarks/render.py --no-plots')
    return stale


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--out', type=Path, default=DOCS,
                        help='directory of benchmarks.md (default: docs/)')
    parser.add_argument('--no-plots', action='store_true',
                        help='only the Markdown blocks')
    parser.add_argument('--check', action='store_true',
                        help='write nothing; exit 1 with a diff if a block '
                             'is not what the stored results render to')
    args = parser.parse_args(argv)
    if args.check:
        try:
            return check(args.out)
        except ValueError as error:
            print(f'render.py --check: {error}')
            return 2
    print(f'Wrote {render(args.out, plots=not args.no_plots)}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
