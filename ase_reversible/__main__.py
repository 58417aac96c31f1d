"""``python -m ase_reversible``: runs :func:`ase_reversible.app.cli.main`."""

import sys

from .app.cli import main

if __name__ == '__main__':
    sys.exit(main(prog='python -m ase_reversible'))
