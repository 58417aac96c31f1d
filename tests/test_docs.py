"""The documentation cannot rot.

- Every ```python block of docs/user-guide.md (and docs/flipbook.md) runs,
  in order, in one namespace, in a fresh directory: the guide's examples assert what the
  prose says, so a change of behaviour breaks this test, not the reader.
- Every relative link (and #anchor) in README.md and docs/*.md leads to an
  existing file (and heading).
- docs/api.md is what docs/make_api.py writes now, covers every name of
  ``ase_reversible.__all__``, and every public name has a docstring.
"""

import importlib.util
import re
import sys
import warnings
from pathlib import Path

import pytest

import ase_reversible
from ase_reversible import AnchorMovedWarning

ROOT = Path(__file__).resolve().parent.parent
DOCS = ROOT / 'docs'
MARKDOWN = [ROOT / 'README.md'] + sorted(DOCS.glob('*.md'))

_FENCE = re.compile(r'^(`{3,}|~{3,})\s*([\w+-]*)')


def load_make_api():
    spec = importlib.util.spec_from_file_location('make_api',
                                                  DOCS / 'make_api.py')
    module = importlib.util.module_from_spec(spec)
    sys.modules['make_api'] = module
    spec.loader.exec_module(module)
    return module


make_api = load_make_api()


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


def anchors(path):
    """The anchors GitHub makes for the headings of a Markdown file."""
    seen = {}
    found = set()
    for line in prose_keeping_headings(path.read_text(encoding='utf-8')):
        match = re.match(r'#{1,6}\s+(.*?)\s*#*\s*$', line)
        if not match:
            continue
        base = make_api.slug(match.group(1))
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

#: Pages whose python blocks run, with the fewest blocks each must keep.
RUNNABLE = {'user-guide.md': 10, 'flipbook.md': 1}


@pytest.mark.parametrize('name', sorted(RUNNABLE))
def test_page_examples_run_in_order(name, tmp_path, monkeypatch):
    page = DOCS / name
    blocks = [(line, code) for language, line, code
              in code_blocks(page.read_text(encoding='utf-8'))
              if language == 'python']
    assert len(blocks) >= RUNNABLE[name], f'{name} lost its examples'
    monkeypatch.chdir(tmp_path)
    namespace = {'__name__': '__docs__'}
    with warnings.catch_warnings():
        # An unintended re-anchoring would mean an example does not show
        # what it claims; the guide catches the one it provokes itself.
        warnings.simplefilter('error', AnchorMovedWarning)
        for line, code in blocks:
            # Padding makes tracebacks point at the line in the guide.
            source = '\n' * (line - 1) + code
            exec(compile(source, str(page), 'exec'), namespace)


@pytest.mark.parametrize('name', sorted(RUNNABLE))
def test_code_blocks_are_closed_and_labelled(name):
    text = (DOCS / name).read_text(encoding='utf-8')
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


# -- (c) the API reference -----------------------------------------------------

def test_api_reference_is_current():
    generated = make_api.render()
    current = (DOCS / 'api.md').read_text(encoding='utf-8')
    assert current == generated, ('docs/api.md is stale: run '
                                  'python docs/make_api.py')


def test_make_api_check_mode(tmp_path, capsys):
    target = tmp_path / 'api.md'
    target.write_text(make_api.render(), encoding='utf-8')
    assert make_api.main(['--check', '--output', str(target)]) == 0
    target.write_text(make_api.render() + 'edited\n', encoding='utf-8')
    assert make_api.main(['--check', '--output', str(target)]) == 1
    assert 'stale' in capsys.readouterr().err


def test_api_reference_covers_every_exported_name():
    text = (DOCS / 'api.md').read_text(encoding='utf-8')
    headings = set(re.findall(r'^#{2,6} `([\w.]+)`', text, flags=re.M))
    missing = []
    for name in ase_reversible.__all__:
        obj = getattr(ase_reversible, name)
        qualified = f'{obj.__module__}.{name}'
        if qualified not in headings and f'ase_reversible.{name}' \
                not in headings:
            missing.append(name)
    assert not missing, f'no section in docs/api.md for {missing}'


def test_every_public_module_is_in_the_reference():
    text = (DOCS / 'api.md').read_text(encoding='utf-8')
    modules = [module.__name__ for module in make_api.public_modules()]
    assert 'ase_reversible.verlet' in modules
    for name in modules:
        assert f'## `{name}`' in text


def test_every_public_name_has_a_docstring():
    missing = make_api.undocumented()
    assert not missing, f"no docstring: {missing}"
