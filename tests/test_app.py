"""The applications' room: what imports what, and the command line's door.

The import rules are read from the source (``ast``), not from what an
interpreter happens to have loaded, so a lazy import inside a function
breaks them as surely as one at the top of a module.
"""

import ast
import runpy
import subprocess
import sys
from pathlib import Path

import pytest

from ase_reversible.app import cli

PACKAGE = Path(__file__).resolve().parent.parent / 'ase_reversible'
APP = PACKAGE / 'app'

# The package's __init__ re-exports Flipbook and __main__ is the command
# line's door: the two places in the package allowed to reach into app.
DOORS = {'__init__.py', '__main__.py'}

# Within app, each module may import only these app modules: one-way, the
# drawing and the systems at the bottom, the command line at the top.
APP_IMPORTS = {
    '__init__': set(),
    'systems': set(),
    'view': set(),
    'flipbook': {'view'},
    'scenes': {'systems', 'view'},
    'demo': {'systems'},
    'cli': {'demo', 'flipbook', 'scenes', 'systems', 'view'},
}


def imported_modules(path):
    """Absolute dotted names of the modules ``path`` imports, anywhere in
    it; ``from X import y`` counts as ``X`` and as ``X.y``, since ``y`` may
    be a module."""
    parts = ['ase_reversible', *path.relative_to(PACKAGE).with_suffix('')
             .parts]
    package = parts[:-1]  # the module's package, for relative imports
    names = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = package[:len(package) - node.level + 1] if node.level \
                else []
            module = '.'.join(base + ([node.module] if node.module else []))
            names.add(module)
            names.update(f'{module}.{alias.name}' for alias in node.names)
    return names


def test_the_core_does_not_import_the_app():
    offenders = {}
    for path in PACKAGE.rglob('*.py'):
        if APP in path.parents or (path.parent == PACKAGE
                                   and path.name in DOORS):
            continue
        hits = {name for name in imported_modules(path)
                if name == 'ase_reversible.app'
                or name.startswith('ase_reversible.app.')}
        if hits:
            offenders[str(path.relative_to(PACKAGE))] = sorted(hits)
    assert offenders == {}


def test_app_modules_are_all_known():
    assert {path.stem for path in APP.glob('*.py')} == set(APP_IMPORTS)


@pytest.mark.parametrize('module', sorted(APP_IMPORTS))
def test_app_imports_go_one_way(module):
    names = imported_modules(APP / f'{module}.py')
    used = {name.split('.')[2] for name in names
            if name.startswith('ase_reversible.app.')} & set(APP_IMPORTS)
    assert used <= APP_IMPORTS[module]


def test_no_cycle_in_the_allowed_imports():
    done, visiting = set(), set()

    def visit(module):
        assert module not in visiting, f'cycle through {module}'
        if module in done:
            return
        visiting.add(module)
        for dependency in APP_IMPORTS[module]:
            visit(dependency)
        visiting.discard(module)
        done.add(module)

    for module in APP_IMPORTS:
        visit(module)


def test_command_line_help_and_unknown_command(capsys):
    assert cli.main(['--help']) == 0
    assert 'flipbook' in capsys.readouterr().out
    assert cli.main([]) == 2
    assert cli.main(['nonsense']) == 2
    assert 'unknown command' in capsys.readouterr().err


def test_command_line_dispatches_to_the_flipbook(tmp_path, capsys):
    png = tmp_path / 'chain.png'
    assert cli.main(['flipbook', 'chain', '--png', '1', '--out',
                     str(png)]) == 0
    assert png.exists()


def test_python_dash_m_runs_the_command_line(monkeypatch, capsys):
    # The package's __main__ as python -m runs it, in this process (the
    # usage-line test below starts a Python of its own).
    monkeypatch.setattr(sys, 'argv', ['ase_reversible', 'demo', '--help'])
    with pytest.raises(SystemExit) as done:
        runpy.run_module('ase_reversible', run_name='__main__',
                         alter_sys=True)
    assert done.value.code == 0
    assert 'python -m ase_reversible demo' in capsys.readouterr().out


# The console script calls cli.main() with no arguments (pyproject.toml,
# checked below): its usage lines must name it, not ``python -m``.
@pytest.mark.parametrize('command', [None, 'demo', 'flipbook', 'lammps'])
def test_usage_lines_name_the_command_as_typed(command, capsys):
    def usage(**prog):
        argv = ['--help'] if command is None else [command, '--help']
        try:
            assert cli.main(argv, **prog) == 0
        except SystemExit as done:  # argparse's --help
            assert done.code == 0
        return next(line for line in capsys.readouterr().out.splitlines()
                    if line.startswith('usage:'))

    typed = ' '.join(['ase-reversible'] + ([command] if command else []))
    assert f' {typed} ' in usage()
    typed = typed.replace('ase-reversible', 'python -m ase_reversible')
    assert f' {typed} ' in usage(prog='python -m ase_reversible')


def test_python_dash_m_names_itself_in_the_usage_line():
    done = subprocess.run([sys.executable, '-m', 'ase_reversible', '--help'],
                          capture_output=True, text=True,
                          cwd=PACKAGE.parent, check=False)
    assert done.returncode == 0, done.stderr
    assert done.stdout.startswith('usage: python -m ase_reversible COMMAND')
    assert 'python -m ase_reversible COMMAND --help' in done.stdout


def test_console_script_points_at_the_command_line():
    pyproject = (PACKAGE.parent / 'pyproject.toml').read_text()
    assert 'ase-reversible = "ase_reversible.app.cli:main"' in pyproject
