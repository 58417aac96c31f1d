"""The command line: the ``ase-reversible`` console script and
``python -m ase_reversible``, both ``COMMAND [options]``.

``demo`` runs :mod:`ase_reversible.app.demo`; ``flipbook`` opens a
:class:`~ase_reversible.Flipbook` on a scene of
:mod:`ase_reversible.app.scenes` or on a trajectory frame; ``lammps`` runs a
LAMMPS input script with exact runs (:mod:`ase_reversible.lammps.script`).
"""

import argparse
import sys
from importlib import import_module
from pathlib import Path

import ase.io
from ase import units

from ..core.record import INFO_KEY
from ..md import ReversibleVerlet
from ..md.replay import (describe, first_difference, replay_from_header,
                         steps_back, steps_behind)
from . import demo
from .flipbook import Flipbook
from .scenes import SCENES
from .systems import AR_EPSILON, AR_RC, AR_SIGMA
from .view import PLANES, AtomsView

COMMANDS = {
    'demo': 'a hot argon cluster run forward, reversed, and back to the bit',
    'flipbook': 'step a simulation forward and backward on demand',
    'lammps': 'a LAMMPS input script with exact runs (under mpiexec)',
}


#: How the console script is called; ``python -m ase_reversible`` passes
#: its own name, so that usage lines show the command that was typed.
PROG = 'ase-reversible'


def main(argv=None, prog=PROG):
    """Dispatch ``argv`` (default ``sys.argv[1:]``) to its command; returns
    the exit status.  ``prog``: the command as typed, for usage lines."""
    argv = sys.argv[1:] if argv is None else argv
    if not argv or argv[0] in ('-h', '--help'):
        print(f'usage: {prog} COMMAND [options]\n')
        for name, what in COMMANDS.items():
            print(f'  {name:9} {what}')
        print(f'\n{prog} COMMAND --help for its options')
        return 0 if argv else 2
    if argv[0] == 'demo':
        return demo.main(argv[1:], prog=f'{prog} demo')
    if argv[0] == 'flipbook':
        return flipbook(argv[1:], prog=f'{prog} flipbook')
    if argv[0] == 'lammps':
        from ..lammps.script import main as lammps_script
        return lammps_script(argv[1:], prog=f'{prog} lammps')
    print(f'unknown command {argv[0]!r}; the commands are '
          f'{", ".join(COMMANDS)} ({prog} --help)', file=sys.stderr)
    return 2


#: ``--calculator`` name -> (module, class, keyword arguments), imported
#: only when chosen: asap3 is optional.
CALCULATORS = {
    'emt': ('ase.calculators.emt', 'EMT', {}),
    'asap3-emt': ('asap3', 'EMT', {}),
    'lj-argon': ('ase_reversible', 'LennardJones',
                 {'epsilon': AR_EPSILON, 'sigma': AR_SIGMA, 'rc': AR_RC}),
}


def flipbook(argv=None, prog='ase-reversible flipbook'):
    """``ase-reversible flipbook``: see ``--help``.

    Returns the exit status.
    """
    parser = argparse.ArgumentParser(
        prog=prog,
        description='Step a simulation forward and backward on demand, '
                    'without storing frames.  Keys: right/left one frame, '
                    'up/down ten, PageUp/PageDown a hundred, Home frame 0.')
    parser.add_argument('source', nargs='?', default='ring',
                        help=f'a scene ({", ".join(SCENES)}; default ring) '
                             'or a trajectory file to start from')
    parser.add_argument('--index', type=int, default=-1,
                        help='frame of the trajectory file (default: last)')
    parser.add_argument('--calculator', choices=sorted(CALCULATORS),
                        help='calculator for a trajectory file')
    parser.add_argument('--timestep', type=float,
                        help='fs (default: the scene\'s; for a new run from '
                             'a file, 5)')
    parser.add_argument('--stride', type=int,
                        help='steps per frame (default: the scene\'s; for '
                             'a file, the steps between its frames, else 1)')
    parser.add_argument('--buffer', metavar='FILE',
                        help='for a file written by ReversibleLangevin, '
                             'ReversibleBussi or an NPT class: the file its '
                             'write_buffer(path) wrote with the frame '
                             'opened; with it the frames are the file\'s, '
                             'bit for bit, forward and back past the frame')
    parser.add_argument('--new-run', action='store_true',
                        help='for a file: start a new ReversibleVerlet run '
                             'from the frame (clock at 0, --timestep and '
                             '--stride or their defaults) instead of '
                             'replaying the dynamics that wrote the file '
                             '(read from its header: class, time step, '
                             'settings, steps between frames); needed for '
                             'a file written by other dynamics')
    parser.add_argument('--plane', choices=sorted(PLANES),
                        help='axes shown (default: the scene\'s; xy)')
    parser.add_argument('--png', type=int, metavar='FRAME',
                        help='render this frame to --out and exit')
    parser.add_argument('--gif', type=int, metavar='FRAMES',
                        help='animate frames 0..FRAMES and back to 0 into '
                             '--out and exit')
    parser.add_argument('--out', help='file for --png or --gif')
    args = parser.parse_args(argv)

    if args.png is None and args.gif is None:
        import matplotlib
        if matplotlib.get_backend().lower() == 'agg':
            print('No interactive matplotlib backend (no display?): use '
                  '--png FRAME --out FILE or --gif FRAMES --out FILE.',
                  file=sys.stderr)
            return 2

    first = 0
    if args.source in SCENES:
        scene = SCENES[args.source]()
        atoms, timestep, stride, view = (scene.atoms, scene.timestep,
                                         scene.stride, scene.view)
        print(scene.description)
        dyn = None
    else:
        path = Path(args.source)
        if not path.exists():
            parser.error(f'{args.source!r} is neither a scene '
                         f'({", ".join(SCENES)}) nor an existing file')
        if args.calculator is None:
            parser.error('a trajectory file needs --calculator '
                         f'({", ".join(sorted(CALCULATORS))})')
        atoms = ase.io.read(path, args.index)
        module, name, kwargs = CALCULATORS[args.calculator]
        try:
            atoms.calc = getattr(import_module(module), name)(**kwargs)
        except ImportError:
            parser.error(f'--calculator {args.calculator} needs {module}, '
                         'which is not installed')
        replay = None
        if args.new_run:
            if args.buffer is not None:
                parser.error('--buffer resumes the run that wrote the file; '
                             'a --new-run starts its own and needs none.')
            # A new run: the frame's record (quanta, clock, a thermostat's
            # state) belongs to the run that wrote it.
            atoms.info.pop(INFO_KEY, None)
        else:
            try:
                replay = recorded_dynamics(path, atoms, args.buffer)
            except ValueError as error:
                parser.error(str(error))
            # The flipbook replays the run with a calculator of the user's
            # choosing: whether its forces are those of the run that wrote
            # the frame is moot (no warning about it).
            record = atoms.info.get(INFO_KEY)
            if isinstance(record, dict):
                record.pop('machine', None)
        timestep, view = 5 * units.fs, AtomsView()
        if replay is not None:
            if args.timestep is not None:
                parser.error(
                    f'--timestep: the flipbook replays the run of '
                    f'{path.name} at its own time step '
                    f'({replay.timestep / units.fs:g} fs); pass --new-run '
                    'to start a new run at another.')
            index = _frames_before(path, args.index)
            try:
                dyn = replay.start(atoms, buffer=args.buffer)
            except (ValueError, OSError) as error:
                parser.error(f'--buffer {args.buffer} (for frame {index} of '
                             f'{path.name}): {error}')
            stride = args.stride or replay.stride
            first = -frames_back(dyn, stride, replay.stride * index)
            _check_replay(parser, dyn, path, index, replay.stride,
                          args.calculator)
            print(f'from the trajectory header: {replay.summary()}, '
                  f'{stride} steps per frame; frame 0 is frame {index} of '
                  f'{path.name}, '
                  + (f'back to frame {first}' if first else
                     'no frames before it'
                     + (' (the run\'s anchor)' if replay.buffered else ''))
                  + (f' (buffer {Path(args.buffer).name})'
                     if args.buffer else ''))
        else:
            dyn, stride = None, 1
            # Never a silent default: the frames shown are a new run's.
            why = '--new-run' if args.new_run \
                else f'no dynamics recorded in {path.name}'
            step = args.timestep or timestep / units.fs
            print(f'{why}: a new ReversibleVerlet run from frame '
                  f'{args.index} at {step:g} fs, {args.stride or stride} '
                  'steps per frame (--timestep, --stride)')
    if args.timestep is not None:
        timestep = args.timestep * units.fs
    if args.stride is not None:
        stride = args.stride
    if args.plane is not None:
        view.plane = args.plane
    if (args.png is not None or args.gif is not None) and not args.out:
        parser.error('--png and --gif need --out FILE')

    if dyn is None:
        dyn = ReversibleVerlet(atoms, timestep)
    book = Flipbook(dyn, stride=stride, view=view, first=first)
    if args.png is not None:
        print('wrote', book.render(args.png, args.out))
        return 0
    if args.gif is not None:
        frames = [*range(args.gif + 1), *range(args.gif - 1, -1, -1)]
        print('wrote', book.save_gif(args.out, frames))
        back = book.frame == 0
        print(f'back at frame 0 after {args.gif} frames each way: {back}')
        return 0
    book.show()
    return 0


def recorded_dynamics(path, atoms, buffer=None):
    """The :class:`~ase_reversible.md.replay.Replay` of the run that wrote
    the frame ``atoms`` of the file at ``path``, from a ``.traj`` file's
    header: the class its ``md-type`` names with every setting the class
    wrote there, the steps between frames as its stride; None where no
    dynamics are recorded (a structure file, a format without a header
    whose frame's restart record names no thermostat).

    ``buffer``: the file the run's ``write_buffer`` wrote with this frame,
    which a frame of Langevin, Bussi or a barostat past its run's anchor
    needs to continue the run bit for bit and to go back past it.

    Raises ValueError, saying which dynamics wrote the file, why its
    frames cannot be shown as the file has them and what to pass instead
    (``--buffer``, ``--new-run``): ASE's own classes and any unknown
    ones, a thermostat frame without its header, or without its buffer
    file, a frame of another run than the header's, a buffer for a
    dynamics that keeps none.
    """
    name = Path(path).name
    new_run = ('Pass --new-run to start a new ReversibleVerlet run from the '
               'frame instead (not the file\'s frames).')
    header = _trajectory_header(path)
    try:
        replay = replay_from_header(header)
    except ValueError as error:
        raise ValueError(f'{name} was {error}. {new_run}') from None
    try:
        if replay is not None:
            replay.check_frame(atoms.info)
    except ValueError as error:
        raise ValueError(f'{name}: {error}. {new_run}') from None
    if replay is None:
        record = atoms.info.get(INFO_KEY)
        sections = sorted(key for key, value in record.items()
                          if isinstance(value, dict)
                          and key not in ('machine', 'dynamics')) \
            if isinstance(record, dict) else []
        if sections:
            raise ValueError(
                f'{name} holds a frame of dynamics whose restart record has '
                f'a {" and ".join(repr(s) for s in sections)} section, but '
                'no header with their settings (a .traj file the run wrote '
                'has one), so its frames cannot be replayed. ' + new_run)
        if buffer is not None:
            raise ValueError(f'--buffer: {name} records no dynamics to '
                             'resume; drop --buffer.')
        return None
    dynamics = replay.dynamics.__name__
    if buffer is not None and not replay.buffered:
        raise ValueError(
            f'--buffer: {name} was written by {dynamics}, which keeps no '
            'buffer: its frames replay exactly without one; drop --buffer.')
    if buffer is None and replay.needs_buffer(atoms.info):
        behind = steps_behind(atoms.info)
        where = 'past its anchor' if behind is None \
            else f'{behind} steps past its anchor'
        raise ValueError(
            f'{name} was written by {describe(header)}. This frame is '
            f'{where}: without the information buffer the run held there, '
            f'{dynamics} would go on with other bits than the file\'s frames '
            'and could not go back past the frame. Pass --buffer FILE, the '
            'file the run\'s write_buffer(path) wrote together with this '
            f'frame. {new_run}')
    return replay


def _check_replay(parser, dyn, path, index, interval, calculator):
    """Refuse (``parser.error``) unless ``dyn`` on frame ``index`` of the
    file at ``path`` reaches the file's next frame (``interval`` steps on)
    or, if there is none and ``dyn`` can run back that far, its previous
    one, bit for bit: the calculator is the user's choice, not the
    header's."""
    back = steps_back(dyn)
    from ase.io.trajectory import Trajectory
    with Trajectory(str(path)) as trajectory:
        if index + 1 < len(trajectory):
            neighbour, steps = index + 1, interval
        elif index > 0 and (back is None or back >= interval):
            neighbour, steps = index - 1, -interval
        else:
            return
        missed = first_difference(dyn, trajectory[neighbour], steps)
    if missed is not None:
        parser.error(
            f'the replay of frame {index} of {path.name} does not reach '
            f'its frame {neighbour} bit for bit (the {missed} differ): the '
            f'calculator (--calculator {calculator}) is not the one the run '
            'used, or the file was written otherwise than its header says. '
            'Pass the run\'s calculator, or --new-run to start a new run '
            'from the frame (not the file\'s frames).')


def frames_back(dyn, stride, steps_in_file):
    """Frames of ``stride`` steps a flipbook on ``dyn`` may go back from
    its frame 0: as many as the file holds before it (``steps_in_file``
    steps), and, for a dynamics with information buffers, no further than
    its anchor of reversal."""
    back = steps_back(dyn)
    steps = steps_in_file if back is None else min(back, steps_in_file)
    return steps // stride


def _frames_before(path, index):
    """Frames of the trajectory at ``path`` before its frame ``index``
    (negative counts from the end)."""
    from ase.io.trajectory import Trajectory
    with Trajectory(str(path)) as trajectory:
        return index if index >= 0 else len(trajectory) + index


def _trajectory_header(path):
    """The description (a dict) an ASE ``.traj`` file's dynamics wrote;
    empty for other files."""
    if Path(path).suffix != '.traj':
        return {}
    from ase.io.trajectory import Trajectory
    try:
        with Trajectory(str(path)) as trajectory:
            return dict(trajectory.description)
    except Exception:  # not a trajectory ASE can open: no header
        return {}
