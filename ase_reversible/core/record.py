"""The restart record: the one owner of what a frame needs to resume.

ASE trajectories store ``atoms.info`` with every frame (JSON, which
round-trips these floats exactly) but not custom per-atom arrays.  The
record holds what, besides the values shown on the atoms, a resumed run
needs to re-encode a frame into the very integers the original run had:
the quantum of every exact variable, keyed ``'<name>_quantum'``, and the
simulated time.  Because quanta are powers of two and integers stay below
2**53, the float64 values of the frame determine those integers exactly.
A variable that the atoms do not show (a thermostat's, say) is stored in
the record itself as its list of counts, keyed by its name.

Sections (dicts by name) hold what else a resumed run reads: a
thermostat's settings, and with every frame the ``'dynamics'`` section --
the class and time step that wrote it, which alone go on with its clock
(:mod:`ase_reversible.md.restart`) -- and the ``'machine'`` section --
the platform that wrote it and digests of the forces and positions at the
frame -- by which a run resumed on another machine sees that its forces
differ (:mod:`ase_reversible.md.machine`).
"""

from __future__ import annotations

import math

import numpy as np

from .codec import check_quantum, on_grid, value_range

INFO_KEY = 'reversible'


def write_record(info: dict, quanta: dict, time: float,
                 hidden: dict | None = None) -> None:
    """Store the quanta and the simulated time in ``info`` (``atoms.info``).

    ``quanta``: ``{name: quantum}`` of every exact variable, e.g.
    ``{'position': ... (Å), 'momentum': ... (amu Å / ASE time unit)}``;
    ``time`` in ASE time units; ``hidden``: ``{name: int64 array}`` of the
    variables the atoms do not show.
    """
    record = _quanta_entries(quanta)
    record['time'] = float(time)
    for name, counts in (hidden or {}).items():
        record[name] = np.asarray(counts).tolist()
    info[INFO_KEY] = record


class RecordWriter:
    """:func:`write_record` for variables the atoms show, with the quanta
    fixed: their entries are made once, not with every step's record.

    ``writer(info, time)`` stores the record of ``quanta`` and ``time``.
    """

    def __init__(self, quanta: dict):
        self._entries = _quanta_entries(quanta)

    def __call__(self, info: dict, time: float, sections=None) -> None:
        """Store the record with ``time`` (ASE time units) in ``info``, and
        ``sections`` (a dict of JSON-ready dicts by name: a thermostat's
        settings, say) if given."""
        # A new dict each time: whoever read an earlier record keeps it.
        info[INFO_KEY] = {**self._entries, 'time': float(time),
                          **(sections or {})}


def _quanta_entries(quanta: dict) -> dict:
    return {f'{name}_quantum': float(q) for name, q in quanta.items()}


def read_record(info: dict, names=('position', 'momentum'),
                hidden=(), sections=()) -> dict | None:
    """The record in ``info``, or None if absent or malformed.

    A dict of floats with the keys ``'<name>_quantum'`` for each of
    ``names`` and ``'time'`` (units as in :func:`write_record`), an
    int64 array of counts for each name in ``hidden``, and for each name
    in ``sections`` the dict stored under it (None if there is none).
    """
    record = info.get(INFO_KEY)
    if not isinstance(record, dict):
        return None
    keys = [f'{name}_quantum' for name in names] + ['time']
    try:
        out = {key: float(record[key]) for key in keys}
    except (KeyError, TypeError, ValueError):
        return None
    if not all(math.isfinite(v) for v in out.values()):
        return None
    for name in hidden:
        try:
            counts = np.array(record[name], dtype=np.int64)
        except (KeyError, TypeError, ValueError, OverflowError):
            return None
        out[name] = counts
    for name in sections:
        section = record.get(name)
        out[name] = dict(section) if isinstance(section, dict) else None
    return out


def record_mismatch(record: dict, shown: dict):
    """Why ``record`` cannot be resumed from, or None if it can.

    ``shown``: ``{name: float array or None}``, the values the atoms show
    of each variable in the record (None: absent, such as momenta never
    set).  A frame the integrator wrote holds whole numbers of quanta,
    exactly; anything else -- a thermostat run, new velocities, moved atoms
    -- was edited since it was written, and its time would be wrong.
    Values that each print exactly in a few decimal places
    (:func:`printed_decimals`) were rounded by a text format, and the
    reason says so.
    """
    try:
        quanta = {name: check_quantum(record[f'{name}_quantum'])
                  for name in shown}
    except ValueError:
        return 'its quanta are not valid'
    present = {name: values for name, values in shown.items()
               if values is not None}
    if not all(np.abs(values).max(initial=0) < 0.5 * value_range(quanta[name])
               for name, values in present.items()):
        return 'the atoms lie outside its range'
    if all(on_grid(values, quanta[name]) for name, values in present.items()):
        return None
    places = [printed_decimals(values) for values in present.values()]
    if None not in places:
        shown_names = ' and '.join(_PLURALS.get(name, name)
                                   for name in present)
        return (f'the {shown_names} have at most {max(places)} decimal '
                'places, rounded by a text format such as extxyz; write '
                'frames with .traj to restart exactly')
    return EDITED


#: :func:`record_mismatch`'s reason for a frame whose positions or momenta
#: were changed after it was written (by another dynamics, ASE's Langevin
#: in an equilibration, or an edit): the atoms are a new start, which
#: needs no warning, as a new dynamics in ASE starts at 0.
EDITED = ('the positions or momenta are not on its grid: they were changed '
          "since the frame was written (by another dynamics, such as ASE's, "
          'or an edit)')


#: The most decimal places a text format is taken to have printed: ASE's
#: extended XYZ writes 8, PDB 3, where a value a run left off its grid
#: (a thermostat's, an edit's) needs 15 or more significant digits.
TEXT_DECIMALS = 10

_PLURALS = {'position': 'positions', 'momentum': 'momenta'}


def printed_decimals(values, most: int = TEXT_DECIMALS):
    """The fewest decimal places, at most ``most``, in which every element
    of ``values`` (float array, any shape) prints exactly, as a text format
    wrote it and read it back; None if there are none.

    Exact: a value read from ``k`` decimals is the float64 nearest
    ``N / 10**k``, which ``rint(v * 10**k) / 10**k`` gives back (one
    correctly rounded division of two exact numbers).
    """
    values = np.asarray(values, dtype=np.float64).ravel()
    for places in range(most + 1):
        scale = 10.0 ** places
        if np.array_equal(np.rint(values * scale) / scale, values):
            return places
    return None
