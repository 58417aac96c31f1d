"""Command line: ``python -m ase_reversible demo``."""

import sys


def main(argv=None):
    argv = sys.argv[1:] if argv is None else argv
    if not argv or argv[0] in ('-h', '--help'):
        print('usage: python -m ase_reversible demo [options]\n'
              '       python -m ase_reversible demo --help')
        return 0 if argv else 2
    if argv[0] == 'demo':
        from .demo import main as demo
        return demo(argv[1:])
    print(f'unknown command {argv[0]!r}; try: python -m ase_reversible demo',
          file=sys.stderr)
    return 2


if __name__ == '__main__':
    sys.exit(main())
