"""``python -m ase_reversible.lammps INPUT``: see :mod:`.script`."""

import sys

from .script import main

if __name__ == '__main__':
    sys.exit(main())
