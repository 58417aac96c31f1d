"""Sub-steps that change momenta through information buffers.

Langevin's friction, Bussi's rescaling and the NPT piston's friction each
multiply momentum counts by a factor that is not a power of two, keeping
the digits that drops in buffers (:mod:`ase_reversible.core.infobuffer`,
:mod:`ase_reversible.core.scaling`) so that the way back can restore them.
What they share lives here: the buffers, keyed by what sets the factor;
the heat the step adds, which the energy check subtracts; both rolled
back with a failed step; and, for the atoms' momenta, which coordinates
are free and the FixCom balance.
"""

from __future__ import annotations

import hashlib
import json
import math

import numpy as np
from ase import units

from ..core import portable
from ..core.compositions import composition_for
from ..core.engine import Engine, InvariantCheck
from ..core.plans import SubStep
from ..core.record import INFO_KEY
from ..errors import AnchorMovedWarning
from ..purity.advice import warn_at_user_line
from .base import ReversibleDynamics
from .checks import checked_seed
from .machine import frame_section


def state_digest(counts):
    """A digest of the exact state (int64 counts by name): what ties a
    buffer file to the frame it was written with."""
    h = hashlib.sha256()
    for name in sorted(counts):
        h.update(np.ascontiguousarray(counts[name], dtype=np.int64).tobytes())
    return h.hexdigest()


def buffer_arrays(prefix, buffers):
    """The arrays of information buffers (by their ratio ``n``) in a
    buffer file: ``{prefix}_{n}_state``, ``_top`` and the used rows of
    ``_words``."""
    arrays = {}
    for n, b in buffers.items():
        depth = int(b.top_k.max(initial=0))
        arrays[f'{prefix}_{n}_state'] = b.state_k
        arrays[f'{prefix}_{n}_top'] = b.top_k
        arrays[f'{prefix}_{n}_words'] = b.words_jk[:depth]
    return arrays


def load_buffer_arrays(prefix, buffers, saved, unknown):
    """Load what :func:`buffer_arrays` wrote under ``prefix`` into
    ``buffers`` (information buffers by ratio ``n``) from ``saved`` (a
    buffer file's arrays by name).  A ratio with no buffer here raises
    ValueError with the message ``unknown(n)``."""
    for key in saved:
        if key.startswith(f'{prefix}_') and key.endswith('_state'):
            n = int(key.split('_')[1])
            buffer = buffers.get(n)
            if buffer is None:
                raise ValueError(unknown(n))
            buffer.load(saved[key], saved[f'{prefix}_{n}_top'],
                        saved[f'{prefix}_{n}_words'])


def resume_point(section, timestep, seed):
    """``(seed, step)`` to go on from: the record's seed and step if its
    ``section`` of a dynamics with noise was written at this size of time
    step (the draws of a step are keyed by both), else a new run from step
    0.  A ``seed`` the user passes wins over the record's; the result is
    checked (:func:`~.checks.checked_seed`: None draws a fresh one)."""
    resumed, step = None, 0
    try:
        if section is not None and float(section['timestep']) == abs(
                timestep):
            resumed, step = int(section['seed']), int(section['step'])
    except (KeyError, TypeError, ValueError):
        pass
    return checked_seed(resumed if seed is None else seed), step


#: How a buffer file shows which dynamics wrote it: an array only that
#: dynamics writes (ReversibleLangevin's files hold none of them).
BUFFER_MARKS = (('buffer_ratios', 'ReversibleBussi'),
                ('pressure_au', 'a barostat'))


class BufferedStep:
    """Information buffers and the heat a step added since the anchor,
    rolled back with a failed step.

    Attributes
    ----------
    heat : float
        Kinetic energy the step added since the anchor (eV).
    buffers : dict
        The step's buffers, by what sets their factor.
    """

    def __init__(self):
        self.buffers = {}
        self.heat = self._saved_heat = 0.0

    def forget(self):
        """Empty the buffers and zero the heat: the anchor moved here."""
        for buffer in self.buffers.values():
            buffer.clear()
        self.heat = self._saved_heat = 0.0

    def active_buffers(self):
        """The buffers that hold digits, by their key."""
        return {n: b for n, b in self.buffers.items() if not b.is_empty()}

    def checkpoint(self):
        """Remember the heat and the buffers."""
        self._saved_heat = self.heat
        for buffer in self.buffers.values():
            buffer.checkpoint()

    def rollback(self):
        """Back to the last :meth:`checkpoint`."""
        self.heat = self._saved_heat
        for buffer in self.buffers.values():
            buffer.rollback()


class BufferedMomentumStep(BufferedStep, SubStep):
    """A sub-step on the atoms' momentum counts (``system.p``, ``[n_atoms,
    3]``) through buffers: :class:`BufferedStep`'s rollback comes before
    :class:`~ase_reversible.core.plans.SubStep`'s.

    The step sees one flat vector of ``size`` coordinates (index ``k``):
    the momenta, then the system's further momentum-like variables
    (``system.thermal_parts()``: rigid bodies' angular momenta), each
    coordinate with its mass and quantum.

    Parameters
    ----------
    system : Hamiltonian
        Its ``'momentum'`` variable is updated.
    settings : callable
        ``settings()`` -> the dynamics' settings (a NamedTuple), read when
        the step is prepared.
    step_of : callable
        ``step_of() -> int``: the index of the step being taken (the one
        before it when going forward, after it when going back), so that
        both ways draw the same noise.
    """

    def __init__(self, system, settings, step_of):
        super().__init__()
        self.system = system
        self.settings = settings
        self.step_of = step_of
        self.shape = system.p.ints.shape
        self._ones_n = np.ones(self.shape[0], dtype=np.int64)
        self.parts = system.thermal_parts()
        self.size = math.prod(self.shape) + sum(
            v.ints.size for v, _ in self.parts)

    def counts_k(self):
        """int64 ``[size]``: the counts the step acts on."""
        x_k = self.system.p.ints.reshape(-1)
        if not self.parts:
            return x_k
        return np.concatenate([x_k] + [v.ints.reshape(-1)
                                       for v, _ in self.parts])

    def mass_k(self):
        """``[size]``: each coordinate's mass (amu; amu Å**2 for an
        angular momentum; 0 for one with no motion)."""
        mass_k = np.repeat(self.system.m_n1[:, 0], 3)
        if not self.parts:
            return mass_k
        return np.concatenate([mass_k] + [m for _, m in self.parts])

    def quantum_k(self):
        """Each coordinate's quantum (a float where all share the
        momentum quantum)."""
        q = self.system.p.quantum
        if not self.parts:
            return q
        return np.concatenate([np.full(math.prod(self.shape), q)] + [
            np.full(v.ints.size, v.quantum) for v, _ in self.parts])

    def free_k(self):
        """bool ``[size]``: the coordinates the step moves (those the
        constraints leave free, with a mass)."""
        free_k = self._free().reshape(-1) != 0
        if not self.parts:
            return free_k
        return np.concatenate([free_k] + [m > 0 for _, m in self.parts])

    def inverse_mass_k(self):
        """``[size]``: ``1 / mass``, 0 where the mass is 0."""
        mass_k = self.mass_k()
        return np.divide(1.0, mass_k, out=np.zeros_like(mass_k),
                         where=mass_k > 0)

    def _free(self):
        """``[n_atoms, 3]``: nonzero where the constraints leave a momentum
        free (the step moves only those)."""
        free_nc = np.ones(self.shape)
        self.system.project(free_nc)
        return free_nc

    def _hold_one_per_component(self, free_k):
        """Under FixCom, take one free coordinate per Cartesian component
        out of ``free_k`` (flat, bool, changed in place) and return them as
        ``[(atom, component)]``; else None.

        The step then moves every other free coordinate, and each held one
        becomes minus the others' sum: the total stays exactly zero, and
        the step stays a bijection the buffer undoes, since the others
        determine it both ways.
        """
        centre = self.system.centre
        if centre is None:
            return None
        held = [(order[0], c) for c, order in enumerate(centre.order_c)
                if len(order)]
        for i, c in held:
            free_k[3 * i + c] = False
        return held

    def hold_total(self, new_k, held):
        """Under FixCom, make each held coordinate (``held``, as
        ``_hold_one_per_component`` returned, or None) of the new
        counts ``new_k`` (flat int64, changed in place) minus the others'
        sum in its component, so that the total is exactly zero."""
        if held is not None:
            new_nc = new_k.reshape(self.shape)
            # One held coordinate per component: each total is read once.
            total_c = np.dot(self._ones_n, new_nc)
            for i, c in held:
                new_nc[i, c] -= total_c[c]

    def _commit(self, x_k, new_k, held, inverse_mass_k):
        """Move the counts from ``x_k`` to ``new_k`` (flat int64, ``[size]``),
        the held coordinates balanced, and add the kinetic energy that
        adds, ``sum (x'**2 - x**2) q**2 / 2m``, to :attr:`heat`."""
        self.hold_total(new_k, held)
        r_k = (new_k - x_k).astype(np.float64)
        both_k = (new_k + x_k).astype(np.float64)
        both_k *= inverse_mass_k
        start = 0
        for v, shape in self._variables():
            end = start + math.prod(shape)
            self.heat += 0.5 * (v.quantum * v.quantum) * portable.dot(
                both_k[start:end], r_k[start:end])
            v.add_integers(r_k[start:end].reshape(shape))
            start = end

    def _variables(self):
        yield self.system.p, self.shape
        for v, _ in self.parts:
            yield v, v.ints.shape


class BufferedDynamics(ReversibleDynamics):
    """What the dynamics with a :class:`BufferedStep` share: the index of
    the step whose noise is drawn (the same both ways), the energy less
    the heat the step added (what the energy check watches), and the
    buffers emptied when the anchor moves.  A subclass sets
    :attr:`buffered_step` before the run starts."""

    #: The sub-step whose buffers and heat the run keeps.
    buffered_step = None

    #: Whether the run keeps information buffers, which a frame past its
    #: anchor needs (from ``write_buffer``) to go on exactly; a
    #: deterministic dynamics built on this class keeps none.
    keeps_buffers = True

    #: The array of :data:`BUFFER_MARKS` this dynamics' buffer files hold
    #: (None: none of them).
    buffer_mark = None

    def _buffered_engine(self, system, scheme, substeps, timestep,
                         energy_check, energy_tolerance):
        """The engine of ``scheme`` (a palindrome of ``(kind,
        coefficient)`` pairs, at second order) over ``substeps`` (by kind)
        on ``system``'s variables, its check watching the energy less the
        heat the buffered step added (every ``energy_check`` steps,
        ``energy_tolerance`` eV)."""
        invariant = InvariantCheck(
            energy_check, energy_tolerance, self._balance,
            self._explain_drift, trigger=self._balance_trigger)
        return Engine(system.variables,
                      tuple((substeps[k], c) for k, c in scheme),
                      composition_for(2, None), timestep,
                      invariant=invariant)

    def _step_of(self):
        # Going back, a step is undone with the noise it was taken with:
        # that of the step before the present index.
        engine = self.engine
        return engine.step_index if engine.direction > 0 \
            else engine.step_index - 1

    def _balance(self):
        energy, proposed = self.system.energy()
        return energy - self.buffered_step.heat, proposed

    def _balance_trigger(self):
        return self.system.kinetic_energy() - self.buffered_step.heat

    def _explain_drift(self, number, drift, tolerance):
        return (
            f'The total energy minus the heat the thermostat added has '
            f'changed by {drift:.4g} eV since the anchor of reversal '
            f'(tolerance {tolerance:.4g} eV) after step {number}: the '
            'integration is unstable. Use a smaller time step (now '
            f'{abs(self.dt) / units.fs:g} fs). The step was not taken; the '
            'state is valid and reverse() leads back exactly. If the change '
            'is expected, raise energy_tolerance or pass energy_check=0.')

    def _install(self, counts):
        # Steps before the new anchor cannot be retraced: their digits go.
        self.buffered_step.forget()
        super()._install(counts)

    @property
    def seed(self) -> int:
        """The key of the noise (fixed at construction)."""
        return self._seed

    @property
    def heat(self) -> float:
        """Kinetic energy the thermostat added since the anchor, eV."""
        return self.buffered_step.heat

    @property
    def buffer_bits(self) -> float:
        """Information the buffers hold, bits (all coordinates; a
        :class:`~ase_reversible.core.scaling.ScalingBuffer` counts its
        stored ratios too and may hold less than an empty one)."""
        return sum(b.bits for b in self.buffered_step.buffers.values())

    def _save_buffer(self, path, arrays, machine=True):
        """Write a buffer file to ``path`` (NumPy ``.npz``): what every
        buffer file holds and ``arrays`` (the dynamics' own, by name).

        Every file holds the seed, the time step, the step and the
        anchor's step, the anchor's counts, the digest of the state now
        and, if ``machine``, the record's machine section.  Refused while
        steps of another size are on the way back to the anchor (one
        buffer file holds one time step)."""
        self._sync()
        engine = self.engine
        if engine.other_step_sizes:
            raise ValueError(
                'Steps with another time step are on the way back to the '
                'anchor; write the buffer after retracing them, or from a '
                'run at one time step.')
        common = {'seed': np.uint64(self._seed), 'timestep': abs(engine.dt),
                  'step': engine.step_index,
                  'anchor_step': engine.anchor_index,
                  'digest': state_digest(engine.snapshot())}
        if machine:
            common['machine'] = json.dumps(self._buffer_machine_section())
        for name, counts in engine.anchor.items():
            common[f'anchor_{name}'] = counts
        with open(path, 'wb') as f:
            np.savez(f, **common, **arrays)

    def _resume(self, engine, step, buffer, settings, load, *,
                settings_optional=False):
        """Start ``engine`` at ``step`` (the draws go on from the step the
        record was written at, so a resumed run draws what the original
        drew); with a ``buffer`` file, take its anchor of reversal and
        hand its arrays to ``load`` (a callable of the arrays by name),
        so the run also goes back past this point.  The file is refused
        unless this dynamics wrote it at this very state, seed, time step,
        step and ``settings`` (by name: the steps behind the frame retrace
        only under the settings they were taken with;
        ``settings_optional``: a file without one is taken).  A frame
        whose record lost its machine section takes the file's.  Without
        a file, a frame of this dynamics' run that had steps behind it
        warns (:meth:`_warn_without_buffer`)."""
        engine.step_index = engine.anchor_index = step
        if buffer is None:
            self._warn_without_buffer(engine, step)
            return
        saved = self._read_buffer(buffer, engine, step, settings,
                                  settings_optional)
        if self._resumed_machine is None and 'machine' in saved:
            self._resumed_machine = json.loads(str(saved['machine']))
        engine.anchor_index = int(saved['anchor_step'])
        engine.anchor = {name: saved[f'anchor_{name}']
                         for name in engine.variables}
        load(saved)

    def _writer_section(self):
        # The step and the anchor's step say whether the way back past a
        # frame needs its buffer file: at the anchor the buffers are empty.
        engine = self.engine
        return {**super()._writer_section(), 'step': engine.step_index,
                'anchor_step': engine.anchor_index}

    def _warn_without_buffer(self, engine, step):
        """Warn once, at construction, if the atoms are a frame of this
        dynamics' run at ``step`` with steps behind it since its anchor
        and no buffer file was given: the buffers those steps filled are
        gone, so the continuation differs from the run's and the way back
        stops at the frame."""
        writer = self._record_writer
        if writer is None or not self._goes_on_with_record(engine.dt):
            return
        try:
            resumed = int(writer['step']) == step
            behind = step - int(writer['anchor_step'])
        except (KeyError, TypeError, ValueError):
            return
        if not resumed or behind == 0:
            return
        name = type(self).__name__
        warn_at_user_line(
            f'These atoms are a frame of a {name} run, {abs(behind)} steps '
            'from its anchor, resumed without the buffer file its '
            'write_buffer() writes: the run goes on with the same random '
            'draws and statistics but not bit for bit as the original '
            'continuation (the digits its buffer held enter the rounding '
            'of the steps to come), and the way back stops at this frame. '
            'To go on exactly and run back past it, call '
            'dyn.write_buffer(path) when the frame is written and pass '
            'buffer=path here; to start a new run from these atoms '
            f'instead, remove the record (atoms.info.pop({INFO_KEY!r})).',
            AnchorMovedWarning)

    def _read_buffer(self, path, engine, step, settings, settings_optional):
        """The arrays of the buffer file at ``path`` by name, checked as
        :meth:`_resume` says."""
        with np.load(path) as f:
            saved = {key: f[key] for key in f.files}
        name = type(self).__name__
        mark, writer = next(((key, who) for key, who in BUFFER_MARKS
                             if key in saved),
                            (None, 'ReversibleLangevin'))
        if mark != self.buffer_mark:
            raise ValueError(f'{path} is not a {name} buffer file '
                             f'(written by {writer}): pass the file the '
                             f'{name} run wrote, or no buffer.')
        problems = []
        if int(saved['seed']) != self._seed:
            problems.append(f'it was written with seed {int(saved["seed"])}, '
                            f'not {self._seed}')
        if float(saved['timestep']) != abs(engine.dt):
            problems.append('its time step is '
                            f'{float(saved["timestep"]) / units.fs:g} fs')
        for setting, value in settings.items():
            if setting not in saved:
                if not settings_optional:
                    problems.append(f'it holds no {setting}')
            elif float(saved[setting]) != value:
                problems.append(f'it was written with {setting}='
                                f'{float(saved[setting])!r}, not {value!r} '
                                '(the way back retraces its steps with it)')
        if int(saved['step']) != step \
                or str(saved['digest']) != state_digest(engine.snapshot()):
            problems.append(f'it was written at step {int(saved["step"])} of '
                            'another state (these atoms are at step '
                            f'{step} by their restart record)')
        if problems:
            raise ValueError(
                f'The buffer file {path} does not belong to these atoms: '
                + '; '.join(problems) + '. Pass the frame that was written '
                'together with it (the last one before write_buffer), or no '
                'buffer to go on without the way back.')
        return saved

    def _buffer_machine_section(self):
        """The record's machine section for the buffer file, with the
        digest of the forces here (computed if no step left them)."""
        system = self.system
        section = frame_section(system, self.atoms.calc, system.purity.mode)
        if 'forces' not in section and 'kick' not in section \
                and system.purity.mode != 'guarded':
            system.kick.forces()
            section = frame_section(system, self.atoms.calc,
                                    system.purity.mode)
        return section
