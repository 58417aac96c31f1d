"""Command line: ``python -m ase_reversible demo`` or ``... flipbook``."""

import sys

COMMANDS = {
    'demo': 'a hot argon cluster run forward, reversed, and back to the bit',
    'flipbook': 'step a simulation forward and backward on demand',
}


def main(argv=None):
    argv = sys.argv[1:] if argv is None else argv
    if not argv or argv[0] in ('-h', '--help'):
        print('usage: python -m ase_reversible COMMAND [options]\n')
        for name, what in COMMANDS.items():
            print(f'  {name:9} {what}')
        print('\npython -m ase_reversible COMMAND --help for its options')
        return 0 if argv else 2
    if argv[0] == 'demo':
        from .demo import main as demo
        return demo(argv[1:])
    if argv[0] == 'flipbook':
        from .flipbook import main as flipbook
        return flipbook(argv[1:])
    print(f'unknown command {argv[0]!r}; try: python -m ase_reversible '
          f'{" or ".join(COMMANDS)}', file=sys.stderr)
    return 2


if __name__ == '__main__':
    sys.exit(main())
