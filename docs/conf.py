"""Sphinx configuration: the Markdown pages of docs/ and an API reference
generated from the package.

    python -m sphinx -W --keep-going -b html docs docs/_build/html

The API pages are written anew at each build into docs/api/ (not
committed) by autosummary, which walks the package recursively: a module
that is added, moved or renamed appears in the reference without editing
any file here.
"""

import importlib
import re
import shutil
from pathlib import Path

import ase_reversible

project = 'ase-reversible'
author = 'the ase-reversible authors'
release = version = ase_reversible.__version__

extensions = [
    'myst_parser',
    'sphinx.ext.autodoc',
    'sphinx.ext.autosummary',
    'sphinx.ext.napoleon',
    'sphinx.ext.viewcode',
]

# The pages are Markdown; autosummary writes its API pages as reST.
source_suffix = {'.md': 'markdown', '.rst': 'restructuredtext'}
root_doc = 'index'
templates_path = ['_templates']
# docs/benchmarks/ and docs/images/ hold data and pictures, not pages.
exclude_patterns = ['_build', 'benchmarks', 'images']

# -- Markdown ---------------------------------------------------------------

# The pages link to headings by GitHub's anchors ("#a-first-reversed-run");
# MyST makes the same anchors for headings down to this level.
myst_heading_anchors = 4

# -- API reference ----------------------------------------------------------

autosummary_generate = True
# Written anew at each build: a page left from a module that has since
# moved would fail to import and fail the build.
shutil.rmtree(Path(__file__).resolve().parent / 'api', ignore_errors=True)
# Submodules come from walking the package, not from __all__ (the package's
# __all__ lists the names to import, not its modules).
autosummary_ignore_module_all = True

# ase_reversible.torch needs PyTorch, an optional dependency: without it
# its pages are built against a stand-in.
try:
    import torch  # noqa: F401
    autodoc_mock_imports = []
except ImportError:
    autodoc_mock_imports = ['torch']

autodoc_member_order = 'bysource'
autodoc_default_options = {'show-inheritance': True}
# Signatures as written; types are explained in the docstrings' Parameters.
autodoc_typehints = 'signature'
autodoc_preserve_defaults = True

napoleon_google_docstring = False
napoleon_numpy_docstring = True
# The docstrings give types in words ("int64 array [n_atoms, 3]", "{'xy',
# 'xz'}, optional"), for people, not as cross-reference targets: render
# them as text.
napoleon_use_param = False
napoleon_use_rtype = False
# An Attributes section as a field list like Parameters: as separate
# attribute entries it would document a second time what autodoc already
# documents (NamedTuple fields, properties).
napoleon_custom_sections = [('Attributes', 'params_style')]


def _exported():
    """Where each name of ``__all__`` is documented, and which are not.

    An object is documented once, in the module that defines it; the
    package page lists the names users import and links there, so the
    links follow a class when it moves to another module.

    Returns ``(targets, inline)``: the names to link to, relative to the
    package, and the names with no other home (defined in the package
    itself, or exported under another name), which the package page
    documents in full.
    """
    targets, inline = [], []
    for name in ase_reversible.__all__:
        obj = getattr(ase_reversible, name)
        module = getattr(obj, '__module__', None) or ''
        try:
            home = importlib.import_module(module) if module else None
        except ImportError:
            home = None
        if module.startswith(ase_reversible.__name__ + '.') \
                and getattr(home, name, None) is obj:
            # Relative to the package, whose page the list is on.
            targets.append(f'{module.partition(".")[2]}.{name}')
        else:
            targets.append(name)
            inline.append(name)
    return targets, inline


_targets, _inline = _exported()
autosummary_context = {
    'package': ase_reversible.__name__,
    'exported': _targets,
    'inline': _inline,
}

# Every cross-reference must resolve: to the package's own documented
# objects (see _resolve_package_name), or, for types of other projects,
# to nothing -- no inventory of theirs can be fetched offline, so they
# are shown as plain names.
nitpicky = True
nitpick_ignore_regex = [
    ('py:.*', r'(ase|numpy|np|scipy|matplotlib|PIL|asap3)(\..*)?'),
]


# -- Hooks ------------------------------------------------------------------

#: NumPy-style sections whose entries are ``name : type`` lines.
_FIELD_SECTIONS = {'Parameters', 'Other Parameters', 'Returns', 'Yields',
                   'Raises', 'Warns', 'Attributes', 'Receives'}
_HEADER_RULE = re.compile(r'-{3,}')
_FIELD_LINE = re.compile(r'[\w*.]+(\s*,\s*[\w*.]+)*(\s*:(\s.*)?)?')


def _end_field_sections(app, what, name, obj, options, lines):
    """Start a Notes section where prose follows a field section.

    Several docstrings end with a paragraph after their Parameters or
    Returns; napoleon would read it as one more entry, so a paragraph
    that cannot be an entry (not ``name`` or ``name : type``) gets a
    heading of its own.  Runs before napoleon.
    """
    section = None
    i = 0
    while i < len(lines):
        line = lines[i]
        if i + 1 < len(lines) and _HEADER_RULE.fullmatch(lines[i + 1].strip()):
            section = line.strip()
            i += 2
            continue
        starts_paragraph = line and not line[0].isspace() \
            and (i == 0 or not lines[i - 1].strip())
        if section in _FIELD_SECTIONS and starts_paragraph \
                and not _FIELD_LINE.fullmatch(line):
            lines[i:i] = ['Notes', '-----']
            section = 'Notes'
            i += 2
        i += 1


def _napoleon_except_attributes(napoleon_hook):
    """Napoleon's docstring hook, not applied to attributes and properties.

    For those, napoleon takes any text before a first colon for a type
    ("A copy of the exact state: int64 ..." would become type "A copy of
    the exact state"); their docstrings here are prose.
    """
    def hook(app, what, name, obj, options, lines):
        if what not in ('attribute', 'data', 'property'):
            napoleon_hook(app, what, name, obj, options, lines)
    return hook


def _lookup(dotted):
    """``(object, canonical dotted name)`` or ``(None, None)``.

    The canonical name is where the object is defined and documented:
    ``ase_reversible.ReversibleVerlet.backpropagate`` gives
    ``ase_reversible.md.base.ReversibleDynamics.backpropagate``.
    """
    parts = dotted.split('.')
    for cut in range(len(parts), 0, -1):
        try:
            obj = importlib.import_module('.'.join(parts[:cut]))
        except ImportError:
            continue
        except Exception:  # a module that fails to import: not ours to judge
            return None, None
        canonical = obj.__name__
        for part in parts[cut:]:
            try:
                obj = getattr(obj, part)
            except AttributeError:
                return None, None
            qualname = getattr(obj, '__qualname__', None)
            module = getattr(obj, '__module__', None)
            if isinstance(module, str) and isinstance(qualname, str) \
                    and '<' not in qualname:
                canonical = f'{module}.{qualname}'
            else:
                canonical = f'{canonical}.{part}'
        return obj, canonical
    return None, None


def _resolve_package_name(app, env, node, contnode):
    """Resolve Python references that Sphinx alone cannot.

    Docstrings name things as users import them
    (``ase_reversible.ReversibleVerlet``) or as their module imports them
    (``Grid`` in verlet.py); each object is documented once, under the
    module that defines it, so such a name is looked up in Python and the
    reference sent to that place.  A name of another project resolves to
    plain text.
    A name that does not exist, or one of this package that is not
    documented, stays unresolved and fails the build.
    """
    if node.get('refdomain') != 'py':
        return None
    target = node['reftarget'].lstrip('~.')
    contexts = [node.get('py:module'), '']
    if node.get('py:module') and node.get('py:class'):
        contexts.insert(0, f"{node['py:module']}.{node['py:class']}")
    for context in contexts:
        obj, canonical = _lookup(f'{context}.{target}' if context else target)
        if canonical is None:
            continue
        if not canonical.startswith(ase_reversible.__name__ + '.'):
            return contnode
        if canonical == node['reftarget']:
            return None
        domain = env.get_domain('py')
        return domain.resolve_xref(env, node['refdoc'], app.builder,
                                   node['reftype'], canonical, node, contnode)
    # A bare name the module does not import by that name (``Grid`` where
    # verlet.py has ``fixedpoint as fp``): accept it if exactly one
    # documented object of the package has it (more than one is an error).
    if '.' not in target and not node.get('refspecific'):
        node['refspecific'] = True
        return env.get_domain('py').resolve_xref(
            env, node['refdoc'], app.builder, node['reftype'], target, node,
            contnode)
    return None


def setup(app):
    from sphinx.ext import napoleon

    replaced = False
    for listener in list(app.events.listeners['autodoc-process-docstring']):
        if listener.handler is napoleon._process_docstring:
            app.disconnect(listener.id)
            replaced = True
    if not replaced:
        raise RuntimeError('napoleon docstring hook not found: update '
                           'docs/conf.py for this version of Sphinx')
    app.connect('autodoc-process-docstring',
                _napoleon_except_attributes(napoleon._process_docstring))
    app.connect('autodoc-process-docstring', _end_field_sections,
                priority=400)
    app.connect('missing-reference', _resolve_package_name)


# -- HTML ---------------------------------------------------------------------

html_theme = 'alabaster'
html_title = f'{project} {release}'
