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

import numpy as np
from ase import units

from ..core import portable
from ..core.plans import SubStep
from .base import ReversibleDynamics
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
    :class:`~ase_reversible.core.plans.SubStep`'s."""

    def __init__(self, system):
        super().__init__()
        self.system = system
        self.shape = system.p.ints.shape
        self._ones_n = np.ones(self.shape[0], dtype=np.int64)

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

    def _commit(self, x_k, new_k, held, inverse_mass_k):
        """Move the momentum counts from ``x_k`` to ``new_k`` (flat int64),
        the held coordinates balanced, and add the kinetic energy that
        adds, ``sum (x'**2 - x**2) q**2 / 2m``, to :attr:`heat`."""
        p = self.system.p
        if held is not None:
            new_nc = new_k.reshape(self.shape)
            # One held coordinate per component: each total is read once.
            total_c = np.dot(self._ones_n, new_nc)
            for i, c in held:
                new_nc[i, c] -= total_c[c]
        r_k = (new_k - x_k).astype(np.float64)
        both_k = (new_k + x_k).astype(np.float64)
        both_k *= inverse_mass_k
        self.heat += 0.5 * (p.quantum * p.quantum) * portable.dot(both_k, r_k)
        p.add_integers(r_k.reshape(self.shape))


class BufferedDynamics(ReversibleDynamics):
    """What the dynamics with a :class:`BufferedStep` share: the index of
    the step whose noise is drawn (the same both ways), the energy less
    the heat the step added (what the energy check watches), and the
    buffers emptied when the anchor moves.  A subclass sets
    :attr:`buffered_step` before the run starts."""

    #: The sub-step whose buffers and heat the run keeps.
    buffered_step = None

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

    def _ready(self):
        self.system.kick.forces()

    def _install(self, counts):
        # Steps before the new anchor cannot be retraced: their digits go.
        self.buffered_step.forget()
        super()._install(counts)

    @property
    def seed(self) -> int:
        """The key of the noise (fixed at construction)."""
        return self._seed

    def _buffer_arrays(self, machine=True):
        """What every buffer file holds (by array name): the seed, the
        time step, the step and the anchor's step, the anchor's counts,
        the digest of the state now and, if ``machine``, the record's
        machine section.  Refused while steps of another size are on the
        way back to the anchor (one buffer file holds one time step)."""
        self._sync()
        engine = self.engine
        if engine.other_step_sizes:
            raise ValueError(
                'Steps with another time step are on the way back to the '
                'anchor; write the buffer after retracing them, or from a '
                'run at one time step.')
        arrays = {'seed': np.uint64(self._seed), 'timestep': abs(engine.dt),
                  'step': engine.step_index,
                  'anchor_step': engine.anchor_index,
                  'digest': state_digest(engine.snapshot())}
        if machine:
            arrays['machine'] = json.dumps(self._buffer_machine_section())
        for name, counts in engine.anchor.items():
            arrays[f'anchor_{name}'] = counts
        return arrays

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
