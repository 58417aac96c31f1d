"""``python -m ase_reversible.lammps INPUT``: see :mod:`.script`."""

import sys

from .script import main

sys.exit(main())
