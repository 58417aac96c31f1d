"""Which machine wrote a frame, and whether this one computes its forces alike.

A run goes back exactly only if every force on the way back has the bits
it had on the way out.  ASE's EMT and LennardJones call ``np.exp``,
numpy powers and BLAS, whose last bits depend on the CPU features numpy
dispatches to and on the BLAS kernels (docs/machines.md has the
measurements); so a frame resumed on another machine may run back along
another path.  Nothing here can make those bits portable; it makes the
difference loud.

Every restart record carries, in its ``'machine'`` section, the platform
that wrote it (:func:`platform`) and a digest of what decides the next
kick at the frame: the forces' float64 bytes, or, under guarded rounding
(which absorbs noise below its bound, so that raw forces would differ
without consequence), the rounded kick in quanta and its scale -- where a
step ends with a drift (drift-kick-drift), those of its last kick, one
drift back, with that drift's ``c h``; and a digest of the positions,
which ties the two to the frame (a record left in ``atoms.info`` while
the positions were set elsewhere on the grid is no frame of that run).
A resumed integrator computes the same at the frame (the forces it needs
for its first kick anyway) and compares (:func:`compare`).

The digests are CRC-32, not a cryptographic hash: they guard against
accident, not intent.  Measured with ``zlib.crc32`` on the 24 kB of 1000
atoms' forces (2-core AMD EPYC, under load from other jobs): 6 µs,
against 26 µs for BLAKE2b and 14 µs for SHA-256.  They are taken where the
record is written -- every step that observers see, and the end of a run
-- from forces the run already holds: no force is computed for them.
"""

from __future__ import annotations

import functools
import platform as _platform
import sys
import warnings
import zlib

import numpy as np

#: The record's section with the platform and the digest.
SECTION = 'machine'


def digest(values, signed_zeros=False) -> str:
    """CRC-32 of a float64 array's bytes, as 8 hex digits.  Unless
    ``signed_zeros``, ``-0.0`` counts as ``0.0``: a kick rounds both to
    the same count, and guarded rounding leaves a count of zero either
    sign by the history noise in a force near zero."""
    if not signed_zeros:
        values = np.add(values, 0.0, dtype=np.float64)
    return f'{zlib.crc32(np.ascontiguousarray(values, np.float64).data):08x}'


def frame_section(system, calc, mode) -> dict:
    """The record's ``'machine'`` section for the present positions of
    ``system`` (a :class:`~.hamiltonian.Hamiltonian`): the platform, and
    the digest the force provider's ``mode`` calls for, if the kick holds
    what it is taken of: at the present positions, or where the last drift
    started (drift-kick-drift), whose ``c h`` (ASE time units) it then
    records as ``'drift'``."""
    section = {'platform': platform(calc)}
    forces, kick = system.kick.held()
    if forces is None and kick is None:
        # Drift-kick-drift: the last kick was before the last drift.
        move = system.drift.last_move()
        if move is None:
            return section
        forces, kick = system.kick.held(move[1])
        section['drift'] = float(move[0])
    if mode == 'guarded':
        if kick is None:
            return section
        section['kick'] = digest(kick[1])
        section['kick_scale'] = float(kick[0])
    elif forces is not None:
        section['forces'] = digest(forces)
    else:
        return section
    # The exact images of the counts: no signed zero to fold.
    section['positions'] = digest(system.atoms.positions, signed_zeros=True)
    return section


def compare(section, system) -> bool | None:
    """Whether the forces here, at the frame ``system`` shows, have the
    recorded digest: True, False, or None if the record has none, or was
    written at other positions.

    Computes the forces (the first kick reuses them) and, for a kick
    digest, rounds a kick at the recorded scale with this machine's force
    provider; changes nothing else."""
    if section.get('positions') != digest(system.atoms.positions,
                                          signed_zeros=True):
        return None
    if 'drift' not in section:
        return _compare_here(section, system)
    # Where the last kick was: one drift back, and forward again as the
    # run came (the momenta do not change, so the rounded increment is
    # the same, negated: the positions return exactly, and the drift and
    # kick hold what a record written now digests).
    try:
        ch = float(section['drift'])
    except (TypeError, ValueError):
        return None
    x, drift = system.x, system.drift
    x.checkpoint()
    try:
        drift.apply(drift.prepare(-ch))
        same = _compare_here(section, system)
        drift.apply(drift.prepare(ch))
    except BaseException:
        x.rollback()
        drift.rollback()
        raise
    return same


def _compare_here(section, system):
    if 'forces' in section:
        return digest(system.kick.forces()) == section['forces']
    if 'kick' in section:
        try:
            scale = float(section['kick_scale'])
        except (KeyError, TypeError, ValueError):
            return None
        shape = system.x.ints.shape
        r_nc = np.empty(shape)
        system.purity.rounded_kick(system.atoms, system.kick.forces(), scale,
                                   system.project, out=r_nc,
                                   scratch=np.empty(shape))
        if system.centre is not None:
            # The kick digested was balanced so (a total momentum held).
            system.centre.balance(r_nc)
        return digest(r_nc) == section['kick']
    return None


def platform(calc) -> dict:
    """What decides the last bits of floating-point results here, as a
    small JSON-ready dict: machine architecture, numpy and the SIMD
    targets it dispatches to, the BLAS and OpenMP libraries loaded (from
    threadpoolctl, if installed: kernel and threads), ASE, and the
    calculator's class and package version."""
    # A copy each time: a record's reader may modify what it holds.
    return dict(_platform_of(type(calc)))


@functools.lru_cache(maxsize=None)
def _platform_of(cls):
    return {**_software(), 'calculator': _calculator(cls)}


@functools.cache
def _software():
    import ase
    out = {'arch': _platform.machine(), 'numpy': np.__version__,
           'simd': _simd(), 'ase': ase.__version__}
    libraries = _libraries()
    if libraries:
        out['libraries'] = libraries
    return out


def _simd():
    try:
        from numpy._core import _multiarray_umath as umath
    except ImportError:  # numpy 1.x
        from numpy.core import _multiarray_umath as umath
    features = getattr(umath, '__cpu_features__', {})
    dispatch = getattr(umath, '__cpu_dispatch__', ())
    baseline = getattr(umath, '__cpu_baseline__', ())
    on = [name for name in dispatch if features.get(name)]
    return ' '.join(list(baseline[-1:]) + on)


def _libraries():
    """The BLAS and OpenMP libraries numpy and others loaded: the kernel
    a BLAS chose (OpenBLAS picks it by CPU) and thread counts.  Looked
    up once per process (threadpoolctl: about 13 ms, measured)."""
    try:
        from threadpoolctl import threadpool_info
        with warnings.catch_warnings():
            # Its advice on mixed OpenMP runtimes is not ours to give here.
            warnings.simplefilter('ignore')
            info = threadpool_info()
    except Exception:  # not installed, or a library it cannot read
        return ''
    return '; '.join(
        ' '.join(str(part) for part in (
            lib.get('internal_api'), lib.get('version'),
            lib.get('architecture'), f"{lib.get('num_threads')} threads")
            if part)
        for lib in info)


def _calculator(cls) -> str:
    package = (cls.__module__ or '').split('.')[0]
    version = getattr(sys.modules.get(package), '__version__', None)
    return f'{cls.__name__} ({package} {version})' if version \
        else f'{cls.__name__} ({package})'


#: What each platform entry is called in messages.
_NAMES = {'arch': 'architecture', 'numpy': 'numpy',
          'simd': "numpy's SIMD targets", 'libraries': 'BLAS/OpenMP',
          'ase': 'ASE', 'calculator': 'calculator'}


def describe(platform_dict) -> str:
    """One line naming a platform (as :func:`platform` returns)."""
    if not isinstance(platform_dict, dict):
        return 'unknown'
    return ', '.join(f'{_NAMES.get(k, k)} {v}' for k, v in
                     platform_dict.items())


def differences(there, here) -> list:
    """Names of the platform entries that differ.  Libraries count as
    differing only where one loaded by both runs differs (kernel,
    threads): which ones a process has loaded depends on what it imported
    before its first record."""
    if not isinstance(there, dict):
        return []
    return [_NAMES.get(k, k) for k in sorted(set(there) | set(here))
            if (_libraries_differ(there.get(k), here.get(k))
                if k == 'libraries' else there.get(k) != here.get(k))]


def _libraries_differ(there, here) -> bool:
    def by_library(text):
        # 'openblas 0.3.31 SkylakeX 2 threads' -> {'openblas 0.3.31': ...}
        entries = str(text or '').split('; ')
        return {' '.join(e.split()[:2]): e for e in entries if e}
    a, b = by_library(there), by_library(here)
    return any(a[name] != b[name] for name in a.keys() & b.keys())


def explain(differ, there, here, time_fs, dropped) -> str:
    """The :class:`~ase_reversible.MachineChangedWarning` message.

    ``differ``: the forces differ (else the record had no digest and
    another platform); ``there``, ``here``: the platforms; ``time_fs``:
    the frame's time; ``dropped``: a Langevin buffer's way back was
    dropped."""
    names = differences(there, here)
    why = (f' ({", ".join(names)} differ)' if names else
           ' (the platforms look alike: then the calculator, its settings '
           'or its thread count differ)')
    when = f'(time {time_fs:.6g} fs)'
    what = (f'The forces at this restart frame {when} differ from those the '
            'run that wrote it computed there' if differ else
            f'The restart record of this frame {when} was written on another '
            'platform and has no digest of the forces at the frame (it was '
            'written before the first force call)')
    return (
        f'{what}: this machine {"computes" if differ else "may compute"} '
        f'other forces than the one that wrote the frame{why}. Written on: '
        f'{describe(there)}. Here: {describe(here)}. The run from this frame '
        'is exact and reverses exactly to it, the anchor of reversal; '
        'running back past it leaves the path of the run that wrote it as '
        'soon as one rounded kick comes out otherwise, so it is not to be '
        "trusted to reach that run's earlier states"
        + ('; the way back the buffer file held was dropped, so a step back '
           'past the frame raises RetraceLimitError' if dropped else '')
        + '. To run back past this frame, run on the machine and software '
        'stack that wrote it (same CPU features, numpy, BLAS and thread '
        'counts); see the Machines page of the documentation.')
