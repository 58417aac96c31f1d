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
                        help='fs (default: the scene\'s; for a file, its '
                             'trajectory header\'s, else 5)')
    parser.add_argument('--stride', type=int,
                        help='steps per frame (default: the scene\'s; for '
                             'a file, the steps between its frames, else 1)')
    parser.add_argument('--new-run', action='store_true',
                        help='for a file: start a new ReversibleVerlet run '
                             'from the frame (clock at 0, --timestep and '
                             '--stride or their defaults) instead of '
                             'replaying the dynamics that wrote the file; '
                             'needed for a file written by other dynamics')
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

    dynamics = {}
    if args.source in SCENES:
        scene = SCENES[args.source]()
        atoms, timestep, stride, view = (scene.atoms, scene.timestep,
                                         scene.stride, scene.view)
        print(scene.description)
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
        if args.new_run:
            dynamics = {}
            # A new run: the frame's record (quanta, clock, a thermostat's
            # state) belongs to the run that wrote it.
            atoms.info.pop(INFO_KEY, None)
        else:
            try:
                dynamics = recorded_dynamics(path, atoms)
            except ValueError as error:
                parser.error(str(error))
            # The flipbook replays the run with a calculator of the user's
            # choosing: whether its forces are those of the run that wrote
            # the frame is moot (no warning about it).
            record = atoms.info.get(INFO_KEY)
            if isinstance(record, dict):
                record.pop('machine', None)
        timestep, stride, view = (dynamics.pop('timestep', 5 * units.fs),
                                  dynamics.pop('stride', 1), AtomsView())
        if dynamics:
            print(f'from the trajectory header: time step '
                  f'{timestep / units.fs:g} fs, scheme {dynamics["scheme"]}, '
                  f'order {dynamics["order"]} ({dynamics["composition"]}), '
                  f'{stride} steps per frame')
        else:
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

    book = Flipbook(ReversibleVerlet(atoms, timestep, **dynamics),
                    stride=stride, view=view)
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


def recorded_dynamics(path, atoms=None):
    """What a file records of the ReversibleVerlet run that wrote it, from
    a ``.traj`` file's header: ``timestep`` (ASE time units), ``scheme``,
    ``order``, ``composition`` and, as ``stride``, the steps between its
    frames; empty where no dynamics are recorded (a structure file, a
    format without a header whose frame's restart record names no
    thermostat).

    Without these a frame would be browsed with other dynamics than the
    run's, still exactly reversible but not retracing the file's frames;
    so a file written by any other dynamics (a thermostat, a barostat,
    ASE's own classes, named by the header's ``md-type`` or by a section
    of ``atoms``' restart record, ``atoms.info['reversible']``) raises
    ``ValueError`` saying which dynamics and why they are not replayed.
    """
    header = _trajectory_header(path)
    md_type = header.get('md-type')
    keys = ('timestep', 'scheme', 'order', 'composition')
    if md_type == 'ReversibleVerlet':
        missing = [key for key in keys if key not in header]
        if missing:
            raise ValueError(
                f'{Path(path).name} was written by ReversibleVerlet, but its '
                f'header lacks {", ".join(missing)}: its frames cannot be '
                'replayed; pass --new-run (with --timestep and --stride) to '
                'start a new run from the frame instead.')
        # The sign says which way the run went when the file was opened.
        return {'timestep': abs(float(header['timestep'])),
                'scheme': header['scheme'], 'order': int(header['order']),
                'composition': header['composition'],
                'stride': max(1, int(header.get('interval', 1)))}
    record = {} if atoms is None else atoms.info.get(INFO_KEY)
    sections = sorted(name for name, value in (record or {}).items()
                      if isinstance(value, dict) and name != 'machine') \
        if isinstance(record, dict) else []
    if md_type is None and not sections:
        return {}
    if md_type is not None:
        settings = ', '.join(
            f'{key} {_setting(key, value)}' for key, value in header.items()
            if key in ('timestep', 'temperature_K', 'friction', 'taut',
                       'tdamp', 'pressure_au', 'seed', 'interval'))
        what = f'{md_type}' + (f' ({settings})' if settings else '')
    else:
        what = (f'dynamics whose restart record has a '
                f'{" and ".join(repr(s) for s in sections)} section')
    if 'seed' in header or {'langevin', 'bussi'} & set(sections):
        need = ('replaying it would need that thermostat, its seed and the '
                'noise buffer the run wrote (write_buffer), and the '
                'flipbook replays only ReversibleVerlet runs')
    else:
        need = 'the flipbook replays only ReversibleVerlet runs'
    raise ValueError(
        f'{Path(path).name} was written by {what}: {need}, so its frames '
        'cannot be shown as the file has them. Pass --new-run to start a '
        'new ReversibleVerlet run from the frame instead (not the file\'s '
        'frames).')


def _setting(key, value):
    """A header value for a message, times in fs."""
    if key in ('timestep', 'taut', 'tdamp') and isinstance(value, float):
        return f'{abs(value) / units.fs:g} fs'  # negative: run reversed
    if key == 'friction' and isinstance(value, float):
        return f'{value * units.fs:g} / fs'
    return f'{value}'


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
