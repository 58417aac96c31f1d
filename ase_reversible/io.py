"""The restart record kept in ``atoms.info`` and so in trajectory frames.

ASE trajectories store ``atoms.info`` with every frame (JSON, which
round-trips these floats exactly) but not custom per-atom arrays.  The
record holds what, besides the positions and momenta, a resumed run needs to
re-encode a frame into the very integers the original run had: the two
quanta.  Because quanta are powers of two and integers stay below 2**53, the
float64 positions and momenta of the frame determine those integers exactly.
"""

from __future__ import annotations

import math

INFO_KEY = 'reversible'


def write_record(atoms, grid, time: float) -> None:
    """Store the grid and the simulated time (ASE units) in ``atoms.info``.

    ``atoms.info[INFO_KEY]`` becomes ``{'position_quantum': ... (Å),
    'momentum_quantum': ... (amu Å / ASE time unit), 'time': ... (ASE
    time units)}``.
    """
    atoms.info[INFO_KEY] = {**grid.todict(), 'time': float(time)}


def read_record(atoms) -> dict | None:
    """The record in ``atoms.info``, or None if absent or malformed.

    A dict of floats with the keys ``'position_quantum'``,
    ``'momentum_quantum'`` and ``'time'`` (units as in
    :func:`write_record`).
    """
    record = atoms.info.get(INFO_KEY)
    if not isinstance(record, dict):
        return None
    try:
        out = {key: float(record[key]) for key in
               ('position_quantum', 'momentum_quantum', 'time')}
    except (KeyError, TypeError, ValueError):
        return None
    if not all(math.isfinite(v) for v in out.values()):
        return None
    return out
