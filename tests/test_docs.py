"""The documentation cannot rot.

- Every ```python block of README.md and docs/*.md runs or is marked as a
  sketch.  The pages of ``RUNNABLE`` run all their blocks, in order, in
  one namespace, in a fresh directory: the examples assert what the prose
  says, so a change of behaviour breaks this test, not the reader.  What
  a page takes from the reader ("your atoms") is made small by its entry
  in ``GIVEN``, run before its first block; a page that needs an optional
  module (``NEEDS``: torch) is skipped without it, with the reason.  A
  block whose first line starts with ``# sketch:`` (the rest of the line
  says what it leaves out: a CUDA device, the reader's own data) is not
  run; any other python block on a page not in ``RUNNABLE`` is an error.
- Every relative link (and #anchor) in README.md and docs/*.md leads to an
  existing file (and heading).
- Every name of ``ase_reversible.__all__``, and every public class,
  function and method of every module of the package, has a docstring:
  the API reference (Sphinx, docs/conf.py) is made of them, and autodoc
  leaves out what has none without a word.
"""

import importlib
import inspect
import pkgutil
import re
import warnings
from pathlib import Path

import pytest

import ase_reversible
from ase_reversible import AnchorMovedWarning
from tiers import tiered

ROOT = Path(__file__).resolve().parent.parent
DOCS = ROOT / 'docs'
MARKDOWN = [ROOT / 'README.md'] + sorted(DOCS.glob('*.md'))

_FENCE = re.compile(r'^(`{3,}|~{3,})\s*([\w+-]*)')



# -- Markdown parsing --------------------------------------------------------

def code_blocks(text):
    """``(language, first line number, code)`` of each fenced block."""
    blocks = []
    lines = text.split('\n')
    i = 0
    while i < len(lines):
        match = _FENCE.match(lines[i])
        if not match:
            i += 1
            continue
        fence, language = match.groups()
        start = i + 1
        i += 1
        while i < len(lines) and not (
                lines[i].startswith(fence[0] * len(fence))
                and not lines[i].strip(fence[0]).strip()):
            i += 1
        blocks.append((language, start + 1, '\n'.join(lines[start:i])))
        i += 1
    return blocks


def prose(text):
    """``text`` without fenced blocks and inline code (links there are
    examples, not links)."""
    kept, inside = [], None
    for line in text.split('\n'):
        match = _FENCE.match(line)
        if inside is None and match:
            inside = match.group(1)
            kept.append('')
            continue
        if inside is not None:
            if line.startswith(inside[0] * len(inside)) \
                    and not line.strip(inside[0]).strip():
                inside = None
            kept.append('')
            continue
        kept.append(re.sub(r'(`+).*?\1', '', line))
    return '\n'.join(kept)


def slug(heading):
    """The anchor GitHub gives a Markdown heading (before de-duplication);
    MyST makes the same ones (``myst_heading_anchors`` in docs/conf.py)."""
    text = re.sub(r'\[([^\]]*)\]\([^)]*\)', r'\1', heading)  # links
    text = re.sub(r'[`*]', '', text).strip().lower()
    text = re.sub(r'[^\w\- ]', '', text)
    return text.replace(' ', '-')


def anchors(path):
    """The anchors GitHub makes for the headings of a Markdown file."""
    seen = {}
    found = set()
    for line in prose_keeping_headings(path.read_text(encoding='utf-8')):
        match = re.match(r'#{1,6}\s+(.*?)\s*#*\s*$', line)
        if not match:
            continue
        base = slug(match.group(1))
        count = seen.get(base, 0)
        seen[base] = count + 1
        found.add(base if count == 0 else f'{base}-{count}')
    text = path.read_text(encoding='utf-8')
    found.update(re.findall(r'<a\s+(?:id|name)="([^"]+)"', text))
    return found


def prose_keeping_headings(text):
    """Lines outside fenced blocks, inline code kept (headings use it)."""
    inside = None
    for line in text.split('\n'):
        match = _FENCE.match(line)
        if inside is None and match:
            inside = match.group(1)
            continue
        if inside is not None:
            if line.startswith(inside[0] * len(inside)) \
                    and not line.strip(inside[0]).strip():
                inside = None
            continue
        yield line


def links(text):
    """Targets of Markdown links and images, and of HTML src/href."""
    body = prose(text)
    targets = re.findall(r'!?\[(?:[^\[\]]|\[[^\]]*\])*\]\(\s*<?([^)\s>]+)>?'
                         r'(?:\s+"[^"]*")?\s*\)', body)
    targets += re.findall(r'<(?:img|a)\s[^>]*?(?:src|href)="([^"]+)"', body)
    return targets


# -- (a) the user guide runs ---------------------------------------------------

#: The first line of a python block that is not run (the rest of the line
#: says what the sketch leaves out).
SKETCH = '# sketch:'

#: Pages whose python blocks run, with the fewest blocks each must keep.
RUNNABLE = {'README.md': 1, 'user-guide.md': 11, 'flipbook.md': 1,
            'architecture.md': 1, 'pressure.md': 1, 'ase-dynamics.md': 6,
            'adjoint.md': 2, 'torch.md': 2, 'force-purity.md': 1,
            'machines.md': 1, 'thermostats.md': 5}

_ARGON13 = """
import numpy as np
from ase.calculators.lj import LennardJones
from ase.cluster import Icosahedron
from ase.md.velocitydistribution import thermalize_momenta
atoms = Icosahedron('Ar', 2, latticeconstant=5.26)
atoms.center(vacuum=10.0)
thermalize_momenta(atoms, 40, rng=np.random.default_rng(0))
atoms.calc = LennardJones(sigma=3.4, epsilon=0.0104, rc=8.5)
"""

# README's run writes 2,001 frames (ASE reopens the file for each): an
# argon dimer with the package's LennardJones is the least it can be.
_ARGON2 = """
import numpy as np
from ase import Atoms
from ase.md.velocitydistribution import thermalize_momenta
from ase_reversible import LennardJones
atoms = Atoms('Ar2', positions=[[0, 0, 0], [3.8, 0, 0]])
atoms.center(vacuum=10.0)
thermalize_momenta(atoms, 40, rng=np.random.default_rng(0))
atoms.calc = LennardJones(sigma=3.4, epsilon=0.0104, rc=8.5)
"""

_COPPER13 = """
import numpy as np
from ase.calculators.emt import EMT
from ase.cluster import Icosahedron
from ase.md.velocitydistribution import thermalize_momenta
atoms = Icosahedron('Cu', 2, latticeconstant=3.61)
atoms.center(vacuum=6.0)
thermalize_momenta(atoms, 600, rng=np.random.default_rng(0))
atoms.calc = EMT()
"""

#: What a page's examples take from the reader, made small: the code runs
#: in the page's namespace before its first block.
GIVEN = {
    'README.md': _ARGON2,
    'thermostats.md': _ARGON13,
    'force-purity.md': _COPPER13,
    # machines.md reads the last frame of the reader's run.traj.
    'machines.md': _COPPER13 + """
from ase import units
from ase_reversible import ReversibleVerlet
ReversibleVerlet(atoms, 5 * units.fs, trajectory='run.traj').run(10)
""",
}

#: Modules a page's examples need that the package does not require.
NEEDS = {'torch.md': 'torch'}


def page_path(name):
    """README.md at the root, the others in docs/."""
    return ROOT / name if name == 'README.md' else DOCS / name


def is_sketch(code):
    """Whether a python block is marked as a sketch (not run)."""
    return code.lstrip('\n').startswith(SKETCH)


def python_blocks(page):
    """``(first line number, code)`` of each python block of ``page`` that
    is not a sketch."""
    return [(line, code) for language, line, code
            in code_blocks(page.read_text(encoding='utf-8'))
            if language == 'python' and not is_sketch(code)]


# The flipbook page renders pictures, and README's run writes 2,001
# trajectory frames (6 s here): the long tier.
@pytest.mark.parametrize('name', tiered(sorted(RUNNABLE),
                                        quick=sorted(set(RUNNABLE) - {
                                            'flipbook.md', 'README.md'})))
def test_page_examples_run_in_order(name, tmp_path, monkeypatch):
    if name in NEEDS and not _importable(NEEDS[name]):
        pytest.skip(f'{name}\'s examples need {NEEDS[name]}, which is not '
                    'installed')
    page = page_path(name)
    blocks = python_blocks(page)
    assert len(blocks) >= RUNNABLE[name], f'{name} lost its examples'
    monkeypatch.chdir(tmp_path)
    namespace = {'__name__': '__docs__'}
    exec(GIVEN.get(name, ''), namespace)
    with warnings.catch_warnings():
        # An unintended re-anchoring would mean an example does not show
        # what it claims; the guide catches the one it provokes itself.
        warnings.simplefilter('error', AnchorMovedWarning)
        for line, code in blocks:
            # Padding makes tracebacks point at the line in the guide.
            source = '\n' * (line - 1) + code
            exec(compile(source, str(page), 'exec'), namespace)


@pytest.mark.parametrize('page', MARKDOWN, ids=lambda p: p.name)
def test_every_python_block_runs_or_is_a_sketch(page):
    if page.name in RUNNABLE:
        return
    unmarked = [line for line, _ in python_blocks(page)]
    assert not unmarked, (
        f'{page.name}: python blocks at lines {unmarked} are neither run '
        f'(add the page to RUNNABLE, with what it takes from the reader '
        f'in GIVEN) nor marked as sketches (a first line "{SKETCH} what '
        'it leaves out")')


def test_sketches_are_recognised_and_only_at_the_top():
    text = ('```python\n# sketch: needs a GPU\nx = 1\n```\n\n'
            '```python\nx = 1  # sketch: not a mark\n```\n')
    blocks = [code for language, _, code in code_blocks(text)
              if language == 'python']
    assert [is_sketch(code) for code in blocks] == [True, False]


@pytest.mark.parametrize('name', sorted(RUNNABLE))
def test_code_blocks_are_closed_and_labelled(name):
    text = page_path(name).read_text(encoding='utf-8')
    fences = [line for line in text.split('\n') if _FENCE.match(line)]
    assert len(fences) % 2 == 0, 'an unclosed code fence'
    for language, line, _ in code_blocks(text):
        assert language, f'{name} line {line}: a code block with ' \
                         'no language (python runs, text does not)'


# -- (b) links ----------------------------------------------------------------

@pytest.mark.parametrize('page', MARKDOWN, ids=lambda p: p.name)
def test_relative_links_resolve(page):
    broken = []
    for target in links(page.read_text(encoding='utf-8')):
        if re.match(r'[a-zA-Z][a-zA-Z0-9+.-]*:', target):
            continue  # http:, https:, mailto:
        path_part, _, anchor = target.partition('#')
        path = (page.parent / path_part).resolve() if path_part else page
        if not path.exists():
            broken.append(f'{target}: no such file')
            continue
        if anchor and path.suffix == '.md' and anchor not in anchors(path):
            broken.append(f'{target}: no heading with anchor #{anchor} in '
                          f'{path.name}')
    assert not broken, f'{page.name}: ' + '; '.join(broken)


def test_link_checker_sees_links_and_anchors(tmp_path):
    # The checker must find what it is meant to check, or test_relative_
    # links_resolve would pass on anything.
    page = tmp_path / 'page.md'
    page.write_text('# A `code` Title, here\n\n## Twice\n\n## Twice\n\n'
                    'See [x](#a-code-title-here) and ![p](img.png).\n\n'
                    '```text\n[not a link](nowhere.md)\n```\n',
                    encoding='utf-8')
    assert anchors(page) == {'a-code-title-here', 'twice', 'twice-1'}
    assert links(page.read_text(encoding='utf-8')) == [
        '#a-code-title-here', 'img.png']


# -- (c) docstrings ------------------------------------------------------------

#: Modules that are commands, not API, by their last name (so that they
#: stay skipped wherever they move): their helpers need no docstrings.
COMMAND_MODULES = {'__main__', 'demo'}


def package_modules():
    """Every module of the package, subpackages included, found by walking
    it, so that a new or moved module is checked without editing this."""
    modules = [ase_reversible]
    for info in pkgutil.walk_packages(ase_reversible.__path__,
                                      prefix='ase_reversible.'):
        if info.name.rsplit('.', 1)[-1] in COMMAND_MODULES:
            continue
        # ase_reversible.torch needs PyTorch, an optional dependency.
        if info.name.startswith('ase_reversible.torch') \
                and not _importable('torch'):
            continue
        modules.append(importlib.import_module(info.name))
    return modules


def _importable(module):
    try:
        importlib.import_module(module)
    except ImportError:
        return False
    return True


def own_docstring(obj):
    doc = obj.fget.__doc__ if isinstance(obj, property) else obj.__doc__
    return doc if isinstance(doc, str) and doc.strip() else None


def member_docstring(cls, name):
    """The docstring a member shows: its own, else that of the class of
    this package it overrides (ASE's texts are not counted as ours)."""
    for klass in cls.__mro__:
        if not klass.__module__.startswith('ase_reversible') \
                or name not in vars(klass):
            continue
        value = vars(klass)[name]
        if isinstance(value, (staticmethod, classmethod)):
            value = value.__func__
        doc = own_docstring(value)
        if doc is not None:
            return doc
    return None


def undocumented():
    """Qualified names of public classes, functions, methods and
    properties defined in the package that have no docstring."""
    missing = []
    for module in package_modules():
        if own_docstring(module) is None:
            missing.append(module.__name__)
        for name, obj in vars(module).items():
            if name.startswith('_') or not (
                    inspect.isclass(obj) or inspect.isfunction(obj)) \
                    or obj.__module__ != module.__name__:
                continue
            if own_docstring(obj) is None:
                missing.append(f'{module.__name__}.{name}')
            if not inspect.isclass(obj):
                continue
            for member, value in vars(obj).items():
                if isinstance(value, (staticmethod, classmethod)):
                    value = value.__func__
                if (member.startswith('_') and member != '__call__') \
                        or not (isinstance(value, property)
                                or inspect.isfunction(value)):
                    continue
                if member_docstring(obj, member) is None:
                    missing.append(f'{module.__name__}.{name}.{member}')
    return missing


def test_every_exported_name_has_a_docstring():
    missing = [name for name in ase_reversible.__all__
               if own_docstring(getattr(ase_reversible, name)) is None]
    assert not missing, f'no docstring: {missing}'


def test_every_public_name_has_a_docstring():
    missing = undocumented()
    assert not missing, f'no docstring: {missing}'


def test_docstring_check_sees_what_is_missing():
    # undocumented() must find a missing docstring, or the test above
    # would pass on anything.
    assert 'ase_reversible.md.verlet' in {
        module.__name__ for module in package_modules()}

    class Documented:
        """Here."""

        def method(self):
            pass

    Documented.__module__ = 'ase_reversible.scratch'
    assert member_docstring(Documented, 'method') is None


def test_the_readme_says_how_to_get_the_cpu_torch():
    """PyPI's pinned torch is a CUDA build of about 3 GB on most machines:
    the README's torch line gives the CPU index that installs the 190 MB
    wheel, with both pip spellings."""
    readme = (ROOT / 'README.md').read_text()
    text = ' '.join(readme.split())
    assert '--extra-index-url https://download.pytorch.org/whl/cpu' in text
    assert "`--index-url` the same address for `pip install 'torch==" in text
