"""Replaying the run that wrote a trajectory: its dynamics from the header.

Every reversible dynamics writes its settings into a ``.traj`` file's
header (its ``todict()``, which ASE stores as the trajectory's
description together with ``interval``, the steps between frames), and
every frame carries its restart record (:mod:`.restart`).  The header's
``'md-type'`` names the class; every other entry but those of
:data:`DESCRIPTION` is a keyword argument of that class's constructor,
so the class's signature is the table that maps a header to a
constructor call: nothing here repeats a class's settings.

A frame of a dynamics with information buffers (Langevin, Bussi, the
barostats) steps behind its anchor of reversal continues the file's run
bit for bit, and runs back past the frame, only with the buffer file the
run's ``write_buffer(path)`` wrote together with the frame; a frame at
its anchor (the run's first) and a frame of a deterministic dynamics
(Verlet, Nosé) need none.
"""

from __future__ import annotations

import inspect
from typing import NamedTuple

import numpy as np
from ase import units

from .buffered import BufferedDynamics
from .bussi import ReversibleBussi
from .langevin import ReversibleLangevin
from .nose import ReversibleNose
from .npt import ReversibleIsotropicNPT, ReversibleNPT
from .npt.cell_nose import ReversibleNoseNPT
from .npt.nose import ReversibleIsotropicNoseNPT
from .restart import written_by
from .verlet import ReversibleVerlet

#: The dynamics a header's ``'md-type'`` may name, by class name.
REPLAYABLE = {cls.__name__: cls for cls in (
    ReversibleVerlet, ReversibleLangevin, ReversibleBussi, ReversibleNose,
    ReversibleIsotropicNPT, ReversibleNPT, ReversibleIsotropicNoseNPT,
    ReversibleNoseNPT)}

#: Header entries that are not constructor settings: ASE's kind and class
#: of dynamics, the signed time step (its sign is the direction the run
#: went when the file was opened), the steps between frames, and the
#: force-purity mode, which the calculator the frames are replayed with
#: chooses again (it changes how forces are checked, not their bits).
DESCRIPTION = ('type', 'md-type', 'timestep', 'interval', 'force_purity')

#: Settings that are times (ASE time units) and rates (1 / ASE time
#: unit), shown in fs and 1 / fs (a pressure, eV / Å^3, in bar).
_TIMES = ('timestep', 'taut', 'tdamp', 'pdamp')
_RATES = ('friction',)


class Replay(NamedTuple):
    """How to replay the run that wrote a trajectory.

    Attributes
    ----------
    dynamics : type
        The reversible dynamics class that wrote it.
    timestep : float
        ``|dt|``, ASE time units.
    settings : dict
        The other keyword arguments of ``dynamics``' constructor, from the
        header (temperature, friction, seed, damping times, pressure,
        scheme, order, composition, quanta, ... as the class wrote them).
    stride : int
        Steps between the file's frames (>= 1).
    """

    dynamics: type
    timestep: float
    settings: dict
    stride: int

    @property
    def buffered(self) -> bool:
        """Whether the dynamics keeps information buffers, which a frame
        resumed past its anchor needs from the run's buffer file."""
        return keeps_buffers(self.dynamics)

    def needs_buffer(self, info) -> bool:
        """Whether the frame whose ``atoms.info`` is ``info`` continues the
        file's run exactly only with a buffer file: a buffered dynamics'
        frame with steps behind it since its anchor, or one whose record
        does not say (a record written before records counted steps)."""
        if not self.buffered:
            return False
        behind = steps_behind(info)
        return behind is None or behind != 0

    def check_frame(self, info):
        """Raise ValueError unless the restart record in ``info``
        (``atoms.info``) was written by this dynamics at this time step: a
        frame of another run (a file that mixes runs) would start a new
        clock and fresh thermostat state, not the file's run.  A record
        that names no dynamics (an older one) passes, as it does for the
        constructors."""
        writer = written_by(info)
        if writer is None:
            return
        name = self.dynamics.__name__
        try:
            same = (writer['class'] == name
                    and float(writer['timestep']) == self.timestep)
        except (KeyError, TypeError, ValueError):
            same = False
        writer = writer if isinstance(writer, dict) else {}
        if not same:
            raise ValueError(
                f'the header names {name} at '
                f'{self.timestep / units.fs:g} fs but the frame\'s restart '
                f'record was written by {writer.get("class")} at '
                f'{_setting("timestep", writer.get("timestep"))}: the file '
                'holds frames of another run, which this frame does not '
                'continue')

    def summary(self):
        """``'ReversibleLangevin, time step 2 fs, temperature_K 60, ...'``:
        the class and its settings, times in fs, the quanta left out."""
        return ', '.join([self.dynamics.__name__,
                          f'time step {self.timestep / units.fs:g} fs',
                          *_settings_shown(self.settings)])

    def start(self, atoms, buffer=None):
        """The dynamics on ``atoms`` (a frame of the file, its restart
        record in ``atoms.info``), resuming the run there: clock, quanta,
        thermostat state and, with ``buffer`` (the file ``write_buffer``
        wrote with the frame), the way back past it."""
        extra = {} if buffer is None else {'buffer': buffer}
        return self.dynamics(atoms, self.timestep, **self.settings, **extra)


def replay_from_header(header):
    """The :class:`Replay` of the run a trajectory header (``dict``: its
    description) records, or None if it records no dynamics (no
    ``'md-type'``: a structure file).

    Raises ValueError, saying which dynamics wrote the file, where the
    flipbook cannot replay them: ASE's own classes or any other that is
    not in :data:`REPLAYABLE` (their frames are not exactly reversible),
    or a header that lacks a setting its class needs or holds one its
    class does not take (written by another version)."""
    md_type = header.get('md-type')
    if md_type is None:
        return None
    dynamics = REPLAYABLE.get(md_type)
    if dynamics is None:
        raise ValueError(
            f'written by {describe(header)}, which is not one of the '
            f'reversible dynamics ({", ".join(REPLAYABLE)}): only these '
            'retrace their frames exactly')
    # The constructor's own: a class with a __new__ that dispatches
    # (thermostat='nose') would show that one's (*args, **kwargs).
    parameters = dict(inspect.signature(dynamics.__init__).parameters)
    parameters.pop('self', None)
    settings = {key: value for key, value in header.items()
                if key not in DESCRIPTION}
    unknown = [key for key in settings if key not in parameters
               or parameters[key].kind is inspect.Parameter.VAR_KEYWORD]
    missing = [name for name, p in parameters.items()
               if p.default is inspect.Parameter.empty
               and p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY)
               and name not in ('atoms', 'timestep', *settings)]
    if 'timestep' not in header:
        missing.insert(0, 'timestep')
    if unknown or missing:
        problems = [f'{kind} {", ".join(keys)}' for kind, keys in (
            ('lacks', missing), (f'holds settings {md_type} does not take:',
                                 unknown)) if keys]
        raise ValueError(
            f'written by {describe(header)}, but its header '
            f'{" and ".join(problems)} (another version of ase_reversible '
            'wrote it?), so its run cannot be rebuilt')
    return Replay(dynamics, abs(float(header['timestep'])), settings,
                  max(1, int(header.get('interval', 1))))


def first_difference(dyn, frame, steps):
    """What of the file's ``frame`` (``ase.Atoms``, the frame ``steps``
    steps from where ``dyn`` stands; negative: before it) ``dyn`` does not
    reach bit for bit when run there -- ``'positions'``, ``'momenta'`` or
    ``'cell'`` -- or None if it reaches all three.  ``dyn`` is run back
    exactly, so it ends where it started.

    The header gives the dynamics' settings but not the calculator, which
    the user names: a frame the replay misses means another calculator
    (or another setting) than the run's, and the frames shown would not be
    the file's."""
    def run(n):
        if n < 0:
            dyn.reverse()
        try:
            dyn.run(abs(n))
        finally:
            if n < 0:
                dyn.reverse()

    run(steps)
    try:
        atoms = dyn.atoms
        for what, shown, wanted in (
                ('positions', atoms.positions, frame.positions),
                ('momenta', atoms.get_momenta(), frame.get_momenta()),
                ('cell', atoms.cell[:], frame.cell[:])):
            if not np.array_equal(shown, wanted):
                return what
        return None
    finally:
        run(-steps)


def keeps_buffers(dynamics):
    """Whether the dynamics class ``dynamics`` keeps information buffers
    (:attr:`~.buffered.BufferedDynamics.keeps_buffers`)."""
    return issubclass(dynamics, BufferedDynamics) and dynamics.keeps_buffers


def steps_behind(info):
    """Steps the frame whose ``atoms.info`` is ``info`` stands past its
    run's anchor of reversal, by its restart record: 0 at the anchor;
    None where the record does not count them (a deterministic dynamics'
    record, an older record, none)."""
    writer = written_by(info)
    try:
        return int(writer['step']) - int(writer['anchor_step'])
    except (KeyError, TypeError, ValueError):
        return None


def steps_back(dyn):
    """Steps ``dyn`` can run back from where it stands: to its anchor for
    a dynamics with information buffers (past it there is nothing to
    undo); None for the others, which retrace any number of steps."""
    if not keeps_buffers(type(dyn)):
        return None
    return abs(dyn.engine.step_index - dyn.engine.anchor_index)


def describe(header):
    """``'ReversibleLangevin (timestep 2 fs, temperature_K 60, ...)'``:
    the class a trajectory header names and its settings, times in fs,
    the quanta and the force-purity mode left out."""
    settings = ', '.join(_settings_shown(header))
    name = header.get('md-type', 'unnamed dynamics')
    return f'{name} ({settings})' if settings else name


def _settings_shown(settings):
    """``['key value', ...]`` of a header's or a replay's settings for a
    message, without the kind and class of dynamics, the quanta and the
    force-purity mode."""
    return [f'{key} {_setting(key, value)}' for key, value in settings.items()
            if key not in ('type', 'md-type', 'force_purity',
                           'position_quantum', 'momentum_quantum')]


def _setting(key, value):
    """A header value for a message, times in fs."""
    if key in _TIMES and isinstance(value, float):
        return f'{abs(value) / units.fs:g} fs'  # negative: run reversed
    if key in _RATES and isinstance(value, float):
        return f'{value * units.fs:g} / fs'
    if key == 'pressure_au' and isinstance(value, float):
        return f'{value / units.bar:g} bar'
    return f'{value}'
