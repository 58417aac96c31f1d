"""The restart record of every frame and the checks of a resumed one.

Every frame a reversible dynamics shows carries its restart record in
``atoms.info`` (:mod:`ase_reversible.core.record`): the quanta, the time,
the subclass's sections, the :data:`WRITER` section (which dynamics wrote
it, at which time step) and the ``'machine'`` section (:mod:`.machine`).

A constructor resumes from a record that fits the atoms.  The dynamics
that wrote it (same class, same time step) goes on with its run, clock
included, and once it stands compares the forces there with the digest
the record holds.  Any other dynamics keeps only the quanta (the values
stay exact) and starts its own run, clock at 0, as a new ASE dynamics
does; a record that does not fit is then no concern of it either.
"""

from __future__ import annotations

from ase import units

from ..core.record import EDITED, INFO_KEY, read_record, record_mismatch
from ..errors import AnchorMovedWarning, MachineChangedWarning
from ..purity.advice import warn_at_user_line
from .rigid.system import SECTION as RIGID
from .machine import SECTION as MACHINE, compare, differences, explain, \
    frame_section, platform

#: The record's section that names the dynamics that wrote it:
#: ``{'class': name, 'timestep': |dt|}`` (ASE time units), and for a
#: dynamics with information buffers its ``'step'`` and ``'anchor_step'``.
WRITER = 'dynamics'


def written_by(info):
    """The :data:`WRITER` section of the restart record in ``info``
    (``atoms.info``), or None: no record, or one written before records
    named their dynamics."""
    record = read_record(info, names=(), sections=(WRITER,))
    return record[WRITER] if record else None


def same_dynamics(writer, name, timestep):
    """Whether a frame whose record names ``writer`` (its :data:`WRITER`
    section, or None) goes on with the run of the dynamics class ``name``
    at the time step ``timestep`` (ASE time units, either sign): the class
    and ``|timestep|`` are the record's.  Every dynamics goes on with a
    record that names none (written before records named their
    dynamics), as every dynamics did then."""
    if writer is None:
        return True
    try:
        return (writer['class'] == name
                and float(writer['timestep']) == abs(timestep))
    except (KeyError, TypeError, ValueError):
        return False


def grid_values(atoms):
    """``{name: float array or None}``: the positions and momenta the
    atoms show, which an unedited frame holds on the grid of its record."""
    return {'position': atoms.positions,
            'momentum': atoms.arrays.get('momenta')}


def fitting_record(info, values, sections=()):
    """``(record, mismatch)``: the restart record in ``info`` (read with
    ``sections``) and why it does not fit ``values`` (as
    :func:`grid_values` gives them), None if it fits; ``(None, None)`` if
    there is no record."""
    record = read_record(info, sections=sections)
    if record is None:
        return None, None
    return record, record_mismatch(record, values)


class RestartRecord:
    """The restart record's part of
    :class:`~ase_reversible.md.base.ReversibleDynamics`: writing it into
    every frame, finding the one to resume from, and comparing the forces
    at a resumed frame with the record's digest."""

    _forces_match_record = None
    #: The :data:`WRITER` section of the record on the atoms at
    #: construction, and why that record does not fit them (None: it does,
    #: or there is none).
    _record_writer = _record_unfit = None
    #: Sections of the restart record a subclass writes and reads besides
    #: the quanta and the time (written by ``_record_sections``).
    record_sections = ()

    def _write_frame_record(self):
        """The restart record of the present state into ``atoms.info``: the
        subclass's sections, the dynamics that writes it and the platform
        with the digest of the forces the run holds here
        (:mod:`.machine`)."""
        sections = self._record_sections() or {}
        if self.system.layout is not None:
            sections[RIGID] = self.system.record_section()
        sections[WRITER] = self._writer_section()
        sections[MACHINE] = frame_section(self.system, self.atoms.calc,
                                          self.system.purity.mode)
        self._write_record(self.atoms.info, self.get_time(), sections)

    def _writer_section(self):
        """The :data:`WRITER` section of this dynamics' records."""
        return {'class': type(self).__name__,
                'timestep': abs(self.engine.dt)}

    def _read_writer(self, info):
        """Before the record is read: note which dynamics wrote the one in
        ``info`` (``atoms.info``)."""
        self._record_writer = written_by(info)
        self._record_unfit = None

    def _goes_on_with_record(self, timestep):
        """Whether this dynamics, at ``timestep`` (ASE time units), is the
        one that wrote the record on its atoms (:func:`same_dynamics`):
        then it goes on with that run, clock included."""
        return same_dynamics(self._record_writer, type(self).__name__,
                             timestep)

    def _record_sections(self):
        """``{name: dict}`` for the sections in :attr:`record_sections`, or
        None: what a resumed run needs besides the quanta and the time."""
        return None

    def _grid_values(self, atoms):
        """``{name: float array or None}``: what the atoms show that an
        unedited frame holds on the grid of its record."""
        return grid_values(atoms)

    def _resumable_record(self, atoms):
        """The restart record in ``atoms.info`` if it fits the atoms."""
        record, mismatch = fitting_record(
            atoms.info, self._grid_values(atoms),
            sections=(*self.record_sections, MACHINE))
        if mismatch is None:
            return record
        # Warned by _warn_unfit_record once the time step is known: only
        # the dynamics that wrote the record could have gone on with it.
        self._record_unfit = mismatch
        return None

    def _warn_unfit_record(self, timestep):
        """Warn that the record on the atoms does not fit them, if it was
        written by this dynamics at ``timestep`` and the atoms seem to be
        its frame (rounded by a text format, or outside the record's range
        or quanta): the run it seemed to go on with starts anew.  Atoms
        changed since the frame was written (:data:`EDITED`) are a new
        start the user made, told by nothing."""
        if self._record_unfit in (None, EDITED) \
                or not self._goes_on_with_record(timestep):
            return
        warn_at_user_line(
            f'The restart record in atoms.info does not fit these '
            f'atoms: {self._record_unfit}. This is a new run: new quanta, '
            'time from 0. To resume a run exactly, start from an '
            'unedited .traj frame; to silence this, remove the '
            f'record (atoms.info.pop({INFO_KEY!r})).', AnchorMovedWarning)

    def _warn_rigid_record_unused(self, info):
        """Warn where the record in ``info`` holds rigid bodies that these
        atoms, without their constraint, will not run."""
        record = read_record(info, names=(), sections=(RIGID,))
        if record is not None and record[RIGID] is not None:
            warn_at_user_line(
                'These atoms are a frame of a run of rigid molecules (its '
                'restart record holds their bodies), but they carry no '
                'FixBondLengths or FixLinearTriatomic now: they run as free '
                'atoms, a new run. To go on with the rigid run exactly, set '
                'the constraint again before constructing (ase.io.read '
                'restores it from a .traj frame).', AnchorMovedWarning)

    @property
    def forces_match_record(self):
        """Whether the forces at the restart frame this integrator resumed
        are bitwise those of the run that wrote it (the digest in its
        record): True; False, after a
        :class:`~ase_reversible.MachineChangedWarning` (running back past
        the frame cannot be trusted to reach that run's earlier states);
        None if the integrator did not resume a frame, or its record has no
        digest or was written at other positions."""
        return self._forces_match_record

    def _check_machine(self, section):
        """Compare the forces at a resumed frame with the digest its record
        (``section``, the record's ``'machine'`` dict, or None) holds;
        warn if they differ, or if there is no digest and the platform
        differs.  Returns what :attr:`forces_match_record` reports."""
        if not isinstance(section, dict):
            return None
        same = compare(section, self.system)
        if same is None and 'positions' in section:
            return None  # written at other positions: not this frame's
        there, here = section.get('platform'), platform(self.atoms.calc)
        if same is None and not differences(there, here):
            return None
        if same:
            self._write_frame_record()  # with this machine's digest
            return True
        dropped = self._drop_steps_behind_frame()
        warn_at_user_line(explain(same is False, there, here,
                                  self.get_time() / units.fs, dropped),
                          MachineChangedWarning)
        return False if same is False else None

    def _drop_steps_behind_frame(self):
        """After a resumed frame's forces (or stress) differ from its
        record's: forget the steps behind the frame, if the record kept
        any to retrace (the frame becomes the anchor), else rewrite the
        frame's record with this machine's digest.  Returns whether steps
        were dropped."""
        dropped = self.engine.anchor_index != self.engine.step_index
        if dropped:
            # The steps behind the frame ran under other forces: what was
            # kept to retrace them leads elsewhere here.
            self._install(self.engine.snapshot())
        else:
            self._write_frame_record()
        return dropped
