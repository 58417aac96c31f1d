"""Write docs/api.md, the API reference, from the package's docstrings.

    python docs/make_api.py            # rewrite docs/api.md
    python docs/make_api.py --check    # exit 1 if docs/api.md is stale

Documented: every name in ``ase_reversible.__all__``, and every public
module of the package (found with :mod:`pkgutil`, so new modules appear
without editing this script; ``__main__`` and ``demo`` are skipped) with its
public functions, classes and constants -- those defined in that module
whose names do not start with an underscore -- and the public methods and
properties of each class.  Docstrings are copied verbatim into fenced text
blocks, so NumPy-style sections keep their layout.

The output depends only on the package's own source: docstrings are taken
without inheritance (an override without a docstring would otherwise show
ASE's text, which changes with ASE's version), signatures are rendered here
rather than by ``str(inspect.signature(...))`` (whose quoting of annotations
differs between Python versions), and memory addresses are removed.
``tests/test_docs.py`` checks that docs/api.md is what this script writes.
"""

from __future__ import annotations

import argparse
import importlib
import inspect
import pkgutil
import re
import sys
from pathlib import Path

import ase_reversible

PACKAGE = 'ase_reversible'
OUTPUT = Path(__file__).resolve().parent / 'api.md'
#: Modules that are entry points, not API.
SKIPPED_MODULES = ('__main__', 'demo')
#: Longest constant value written out in full; longer ones are summarised.
MAX_VALUE_LENGTH = 90

_ADDRESS = re.compile(r' at 0x[0-9a-fA-F]+')


# -- what is public ---------------------------------------------------------

def public_modules():
    """The package's public modules, sorted by name."""
    names = sorted(info.name for info in
                   pkgutil.iter_modules(ase_reversible.__path__)
                   if not info.name.startswith('_')
                   and info.name not in SKIPPED_MODULES)
    return [importlib.import_module(f'{PACKAGE}.{name}') for name in names]


def module_members(module):
    """Public classes and functions defined in ``module``, in source order."""
    members = [(name, obj) for name, obj in vars(module).items()
               if not name.startswith('_')
               and (inspect.isclass(obj) or inspect.isfunction(obj))
               and obj.__module__ == module.__name__]
    return sorted(members, key=lambda item: _source_line(item[1]))


def module_constants(module):
    """Public module-level assignments: ``(name, value, comment)``.

    Only names assigned at the top level of the module's own source count
    (imports such as ``units`` do not).  ``comment`` is the ``#:`` comment
    above the assignment, if any.
    """
    comments = assignment_comments(inspect.getsource(module), indent='')
    return [(name, vars(module)[name], comment)
            for name, comment in comments.items()
            if name in vars(module) and not name.startswith('_')
            and not (inspect.isclass(vars(module)[name])
                     or inspect.isfunction(vars(module)[name])
                     or inspect.ismodule(vars(module)[name]))]


def assignment_comments(source, indent):
    """``{name: '#: comment'}`` for assignments at one indentation.

    Names are in source order; the comment is empty where there is none.
    """
    lines = source.splitlines()
    found = {}
    pattern = re.compile(re.escape(indent) + r'([A-Za-z_]\w*)\s*(?::[^=]*)?=(?!=)')
    for number, line in enumerate(lines):
        match = pattern.match(line)
        if not match or match.group(1) in found:
            continue
        comment = []
        above = number - 1
        while above >= 0 and lines[above].strip().startswith('#:'):
            comment.insert(0, lines[above].strip()[2:].strip())
            above -= 1
        found[match.group(1)] = ' '.join(comment)
    return found


def class_members(cls):
    """Public methods and properties a class defines itself, in order.

    ``__call__`` counts as public: it is how instances are used.
    """
    members = []
    for name, obj in vars(cls).items():
        if name.startswith('_') and name != '__call__':
            continue
        if isinstance(obj, (staticmethod, classmethod)):
            obj = obj.__func__
        if isinstance(obj, property) or inspect.isfunction(obj):
            members.append((name, obj))
    return members


def class_attributes(cls):
    """Public data attributes a class defines itself.

    ``(name, value, comment)``, ``comment`` from a ``#:`` line above the
    assignment in the class body.
    """
    fields = set(getattr(cls, '_fields', ()))  # NamedTuple fields
    try:
        comments = assignment_comments(inspect.getsource(cls), ' ' * 4)
    except (OSError, TypeError):
        comments = {}
    return [(name, value, comments.get(name, ''))
            for name, value in vars(cls).items()
            if not name.startswith('_') and name not in fields
            and not (isinstance(value, (property, staticmethod, classmethod))
                     or inspect.isfunction(value) or inspect.isclass(value))]


def docstring(obj):
    """The object's own docstring, cleaned, or None (no inheritance)."""
    doc = obj.fget.__doc__ if isinstance(obj, property) else obj.__doc__
    if not isinstance(doc, str) or not doc.strip():
        return None
    return inspect.cleandoc(doc)


def member_docstring(cls, name, member):
    """A member's docstring, else that of the package class it overrides.

    ``(text, owner)``: ``owner`` is the class the text comes from, or None.
    Only classes of this package are searched, so the result does not
    depend on ASE's version.
    """
    own = docstring(member)
    if own is not None:
        return own, None
    for base in cls.__mro__[1:]:
        if base.__module__.split('.')[0] != PACKAGE or name not in vars(base):
            continue
        value = vars(base)[name]
        if isinstance(value, (staticmethod, classmethod)):
            value = value.__func__
        inherited = docstring(value)
        if inherited is not None:
            return inherited, base
    return None, None


def undocumented():
    """Qualified names of public classes, functions, methods and
    properties that have no docstring of their own."""
    missing = []
    for module in public_modules():
        for name, obj in module_members(module):
            if docstring(obj) is None:
                missing.append(f'{module.__name__}.{name}')
            if inspect.isclass(obj):
                missing += [f'{module.__name__}.{name}.{member}'
                            for member, value in class_members(obj)
                            if member_docstring(obj, member, value)[0]
                            is None]
    return missing


# -- rendering --------------------------------------------------------------

def slug(heading):
    """The anchor GitHub gives a Markdown heading (before de-duplication)."""
    text = re.sub(r'\[([^\]]*)\]\([^)]*\)', r'\1', heading)  # links
    text = re.sub(r'[`*]', '', text).strip().lower()
    text = re.sub(r'[^\w\- ]', '', text)
    return text.replace(' ', '-')


def format_annotation(annotation):
    annotation = getattr(annotation, '__forward_arg__', annotation)
    if isinstance(annotation, str):
        return annotation
    if inspect.isclass(annotation):
        return annotation.__qualname__ if annotation.__module__ == 'builtins' \
            else f'{annotation.__module__}.{annotation.__qualname__}'
    return _ADDRESS.sub('', repr(annotation))


def format_signature(obj, skip_first=False):
    """``(a, b=1, *, c: int = 2) -> float`` from ``inspect.signature``."""
    try:
        signature = inspect.signature(obj)
    except (TypeError, ValueError):
        return None
    parts = []
    star_done = False
    parameters = list(signature.parameters.values())
    if skip_first and parameters:
        parameters = parameters[1:]
    for p in parameters:
        if p.kind == p.KEYWORD_ONLY and not star_done:
            parts.append('*')
            star_done = True
        if p.kind == p.VAR_POSITIONAL:
            star_done = True
            text = f'*{p.name}'
        elif p.kind == p.VAR_KEYWORD:
            text = f'**{p.name}'
        else:
            text = p.name
        if p.annotation is not p.empty:
            text += f': {format_annotation(p.annotation)}'
        if p.default is not p.empty:
            default = _ADDRESS.sub('', repr(p.default))
            text += (f' = {default}' if p.annotation is not p.empty
                     else f'={default}')
        parts.append(text)
        if p.kind == p.POSITIONAL_ONLY and (
                p is parameters[-1]
                or parameters[parameters.index(p) + 1].kind
                != p.POSITIONAL_ONLY):
            parts.append('/')
    text = f'({", ".join(parts)})'
    if signature.return_annotation is not signature.empty \
            and not skip_first:
        text += f' -> {format_annotation(signature.return_annotation)}'
    return text


def class_signature(cls):
    """The constructor's signature, or None if it comes from a builtin."""
    for klass in cls.__mro__:
        if '__init__' in vars(klass) or '__new__' in vars(klass):
            if klass.__module__ == 'builtins':
                return None
            method = vars(klass).get('__init__', vars(klass).get('__new__'))
            if isinstance(method, staticmethod):
                method = method.__func__
            if not inspect.isfunction(method):
                return None
            text = format_signature(method, skip_first=True)
            return text
    return None


def format_value(value):
    """A constant's value for the reference, short and address-free."""
    if isinstance(value, (tuple, list)) and value and all(
            inspect.isclass(v) for v in value):
        # Names only: where ASE defines a class moves between versions.
        return f'({", ".join(v.__qualname__ for v in value)})'
    text = _ADDRESS.sub('', repr(value))
    if len(text) <= MAX_VALUE_LENGTH:
        return text
    if isinstance(value, dict):
        keys = ', '.join(repr(k) for k in value)
        text = f'{type(value).__name__} with keys {keys}'
        if len(text) <= 2 * MAX_VALUE_LENGTH:
            return text
    return f'{type(value).__name__} (see the source)'


def fence(text, language='text'):
    """``text`` in a fenced block that no backtick run inside can close."""
    longest = max((len(run) for run in re.findall(r'`+', text)), default=0)
    ticks = '`' * max(3, longest + 1)
    return f'{ticks}{language}\n{text}\n{ticks}'


def doc_block(obj):
    doc = docstring(obj)
    return fence(doc) if doc else '*No docstring.*'


def table_cell(text):
    """``text`` safe inside a Markdown table cell."""
    return text.replace('|', '\\|')


def summary(obj):
    doc = docstring(obj)
    return doc.split('\n\n')[0].replace('\n', ' ') if doc else ''


def kind_of(obj):
    if inspect.isclass(obj):
        return 'exception' if issubclass(obj, BaseException) else 'class'
    return 'function'


def render_object(qualname, obj, level):
    """Section for a class or function named ``qualname``."""
    hashes = '#' * level
    out = [f'{hashes} `{qualname}`', '']
    short = qualname.rsplit('.', 1)[-1]
    if inspect.isclass(obj):
        signature = class_signature(obj)
        out += [fence(f'class {short}{signature or ""}', 'python'), '']
        bases = [b for b in obj.__bases__ if b is not object]
        if bases:
            names = ', '.join(
                f'`{b.__qualname__}`' if b.__module__ == 'builtins'
                else f'`{b.__module__}.{b.__qualname__}`' for b in bases)
            out += [f'Bases: {names}', '']
        out += [doc_block(obj), '']
        attributes = class_attributes(obj)
        if attributes:
            out += ['Class attributes:', '']
            for name, value, comment in attributes:
                line = f'- `{name} = {format_value(value)}`'
                out.append(f'{line}: {comment}' if comment else line)
            out += ['']
        for name, member in class_members(obj):
            out += [f'{hashes}# `{short}.{name}`', '']
            if isinstance(member, property):
                out += ['*property*', '']
            else:
                signature = format_signature(member, skip_first=True)
                out += [fence(f'{name}{signature}', 'python'), '']
            doc, owner = member_docstring(obj, name, member)
            if owner is not None:
                out += [f'*As `{owner.__name__}.{name}`:*', '']
            out += [fence(doc) if doc else '*No docstring.*', '']
    else:
        out += [fence(f'{short}{format_signature(obj)}', 'python'), '']
        out += [doc_block(obj), '']
    return out


def render():
    """The whole of docs/api.md, as a string."""
    modules = public_modules()
    homes = {}  # id(object) -> heading of its section
    for module in modules:
        for name, obj in module_members(module):
            homes.setdefault(id(obj), f'{module.__name__}.{name}')
    exported = [(name, getattr(ase_reversible, name))
                for name in ase_reversible.__all__]

    out = ['# API reference', '',
           '<!-- Generated by docs/make_api.py from the docstrings; '
           'edits are overwritten. -->', '',
           'Every public name of the package, with its signature and its '
           'docstring as written in the source. Units follow ASE: Å, eV, '
           'amu, ASE time units (`ase.units.fs`), momenta in amu Å / ASE '
           'time unit. Array names end in their shape: `_nc` is '
           '`[n_atoms, 3]`, `_n` is `[n_atoms]`. Task-oriented help is in '
           'the [user guide](user-guide.md).', '',
           'Regenerate with `python docs/make_api.py`; '
           '`tests/test_docs.py` fails when this file is stale.', '',
           '## Contents', '',
           f'- [`{PACKAGE}`](#{slug(PACKAGE)}): the names to import']
    for module in modules:
        out.append(f'- [`{module.__name__}`](#{slug(module.__name__)})')
        for name, obj in module_members(module):
            qualname = f'{module.__name__}.{name}'
            out.append(f'  - [`{name}`](#{slug(qualname)})')
    out += ['', f'## `{PACKAGE}`', '']
    if docstring(ase_reversible):
        out += [fence(docstring(ase_reversible)), '']
    out += ['`from ase_reversible import ...`:', '',
            '| name | kind | summary |', '| --- | --- | --- |']
    inline = []
    for name, obj in exported:
        home = homes.get(id(obj))
        if home is None:
            inline.append((name, obj))
            home = f'{PACKAGE}.{name}'
        out.append(f'| [`{name}`](#{slug(home)}) | {kind_of(obj)} | '
                   f'{table_cell(summary(obj))} |')
    out.append('')
    for name, obj in inline:  # exported, but not from a public module
        out += render_object(f'{PACKAGE}.{name}', obj, 3)

    for module in modules:
        out += [f'## `{module.__name__}`', '', doc_block(module), '']
        constants = module_constants(module)
        if constants:
            out += ['Constants:', '', '| name | value | meaning |',
                    '| --- | --- | --- |']
            for name, value, comment in constants:
                out.append(f'| `{name}` | `{table_cell(format_value(value))}`'
                           f' | {table_cell(comment)} |')
            out.append('')
        for name, obj in module_members(module):
            out += render_object(f'{module.__name__}.{name}', obj, 3)
    text = '\n'.join(out)
    text = re.sub(r'\n{3,}', '\n\n', text).rstrip() + '\n'
    return text


def _source_line(obj):
    try:
        return inspect.getsourcelines(obj)[1]
    except (OSError, TypeError):
        return 0


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--check', action='store_true',
                        help='exit 1 if the file is not what this script '
                             'would write')
    parser.add_argument('--output', type=Path, default=OUTPUT,
                        help='where to write (default: docs/api.md)')
    args = parser.parse_args(argv)
    text = render()
    output = args.output
    if args.check:
        current = output.read_text(encoding='utf-8') if output.exists() \
            else ''
        if current != text:
            print(f'{output} is stale: run python docs/make_api.py',
                  file=sys.stderr)
            return 1
        print(f'{output} is up to date')
        return 0
    output.write_text(text, encoding='utf-8')
    missing = undocumented()
    if missing:
        print('No docstring: ' + ', '.join(missing), file=sys.stderr)
    print(f'wrote {output}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
