"""The command line: ``python -m ase_reversible COMMAND`` and the
``ase-reversible`` console script.

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


def main(argv=None):
    """Dispatch ``argv`` (default ``sys.argv[1:]``) to its command; returns
    the exit status."""
    argv = sys.argv[1:] if argv is None else argv
    if not argv or argv[0] in ('-h', '--help'):
        print('usage: python -m ase_reversible COMMAND [options]\n')
        for name, what in COMMANDS.items():
            print(f'  {name:9} {what}')
        print('\npython -m ase_reversible COMMAND --help for its options')
        return 0 if argv else 2
    if argv[0] == 'demo':
        return demo.main(argv[1:])
    if argv[0] == 'flipbook':
        return flipbook(argv[1:])
    if argv[0] == 'lammps':
        from ..lammps.script import main as lammps_script
        return lammps_script(argv[1:])
    print(f'unknown command {argv[0]!r}; try: python -m ase_reversible '
          f'{" or ".join(COMMANDS)}', file=sys.stderr)
    return 2


#: ``--calculator`` name -> (module, class, keyword arguments), imported
#: only when chosen: asap3 is optional.
CALCULATORS = {
    'emt': ('ase.calculators.emt', 'EMT', {}),
    'asap3-emt': ('asap3', 'EMT', {}),
    'lj-argon': ('ase_reversible', 'LennardJones',
                 {'epsilon': AR_EPSILON, 'sigma': AR_SIGMA, 'rc': AR_RC}),
}


def flipbook(argv=None):
    """``python -m ase_reversible flipbook``: see ``--help``.

    Returns the exit status.
    """
    parser = argparse.ArgumentParser(
        prog='python -m ase_reversible flipbook',
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
                        help='fs (default: the scene\'s; 5 for files)')
    parser.add_argument('--stride', type=int, help='steps per frame')
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
        # The flipbook starts a run of its own at the frame, with a
        # calculator of the user's choosing: whether its forces are those
        # of the run that wrote the frame is moot (no warning about it).
        record = atoms.info.get(INFO_KEY)
        if isinstance(record, dict):
            record.pop('machine', None)
        module, name, kwargs = CALCULATORS[args.calculator]
        try:
            atoms.calc = getattr(import_module(module), name)(**kwargs)
        except ImportError:
            parser.error(f'--calculator {args.calculator} needs {module}, '
                         'which is not installed')
        timestep, stride, view = 5 * units.fs, 1, AtomsView()
    if args.timestep is not None:
        timestep = args.timestep * units.fs
    if args.stride is not None:
        stride = args.stride
    if args.plane is not None:
        view.plane = args.plane
    if (args.png is not None or args.gif is not None) and not args.out:
        parser.error('--png and --gif need --out FILE')

    book = Flipbook(ReversibleVerlet(atoms, timestep), stride=stride,
                    view=view)
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
