"""The Python path's step: ``fix external``'s callback on every rank, the
peer of the compiled ``fix reversible/nve`` (the same rounding, guard and
verdicts, to the bit)."""

from __future__ import annotations

import numpy as np

from ..core.codec import LIMIT, guard_band_crossed, round_odd
from ..purity.settings import guard_bound

#: The callback's verdicts, each reduced by maximum over the ranks.
AMBIGUOUS = 1     # an increment lay within the guard: take the step back
NOT_CANONICAL = 2  # a setup's sort bins held two atoms where it mattered
OUT_OF_RANGE = 4  # forces not finite, or kicks beyond the grid's range
# (8 is reversible/nvt's: s would not stay positive.)
IMPURE = 16       # the compiled fix's own recomputation of a flagged kick
                  # found the run's force beyond the guard's bound


class PythonStep:
    """The kick of the Python path, a part of
    :class:`~.integrator.ReversibleLammps`: it reads the run's grid, scales
    and guard settings from there."""

    def _callback(self, caller, step, nlocal, tag, x, fext):
        """``post_force`` on every rank: round, guard and apply the kick."""
        if self._mode == 'halted':
            return
        np_ = self.lmp.numpy
        f = np_.extract_atom('f')[:nlocal]
        v = np_.extract_atom('v')[:nlocal]
        pending = np_.extract_atom(f'd2_{self.name}_k')[:nlocal]
        y, k = self._scratch(nlocal)
        np.multiply(f, self._scale(nlocal), out=y)
        round_odd(y, out=k)
        # NaN propagates through both: the range test below refuses it.
        r_max = max(float(k.max(initial=0.0)), -float(k.min(initial=0.0)))
        if self._type_scale is None:
            f_max = (r_max + 0.5) / self._scale_min
        else:  # the kicks' largest would overstate it by the mass ratio
            f_max = float(np.abs(f).max(initial=0.0))
        if f_max > self._run_force:
            self._run_force = f_max
        bound = (guard_bound(self.force_noise, self._guard_extent, f_max)
                 * self._scale_max)
        local = 0
        if not r_max < LIMIT / 4:  # also catches NaN
            local |= OUT_OF_RANGE
        elif guard_band_crossed(y, k, bound):
            local |= AMBIGUOUS
        setup = self._mode in ('start', 'redo')
        if setup and not self._sorted_canonically(x[:nlocal]):
            local |= NOT_CANONICAL
        # Each flag's maximum over the ranks (one collective): the maximum
        # of the bit masks would drop AMBIGUOUS beside another rank's
        # NOT_CANONICAL.
        bits = self.world.max(*((local >> b) & 1 for b in range(3)))
        flag = sum(int(bit) << b for b, bit in enumerate(bits))
        np.multiply(k, self.velocity_quantum, out=k)
        if flag & OUT_OF_RANGE:
            self._halt(OUT_OF_RANGE)
            return
        if setup:
            if flag & AMBIGUOUS and flag & NOT_CANONICAL:
                # The clean forces may depend on history after all: take
                # nothing, drift once with the velocities as they are,
                # and let run() undo that drift and retry finer.
                pending[:] = 0.0
                self._halt(NOT_CANONICAL)
                return
            if self._mode == 'redo':
                self._compare_with_noisy(f, tag[:nlocal])
                v += k
            pending[:] = k
            self._mode = 'step'
            return
        v += k
        pending[:] = k
        if flag & AMBIGUOUS:
            self._noisy = (np.array(tag[:nlocal]), f.copy(), bound)
            self._halt(AMBIGUOUS)

    def _scratch(self, nlocal):
        """Two reused ``[nlocal, 3]`` float arrays: fresh ones every step
        cost more than the arithmetic on them."""
        if self._buffers is None or len(self._buffers[0]) < nlocal:
            size = int(nlocal * 1.2) + 16
            self._buffers = (np.empty((size, 3)), np.empty((size, 3)))
        return self._buffers[0][:nlocal], self._buffers[1][:nlocal]

    def _halt(self, flag):
        self._flag = flag
        self._mode = 'halted'
        self.lmp.fix_external_set_vector(f'{self.name}_ext', 1, float(flag))

    def _scale(self, nlocal):
        """Per-atom ``dt/2 ftm2v / (m q_v)`` as a column ``[n, 1]``, or a
        scalar when every type has the same mass."""
        if self._type_scale is None:
            return self._scalar_scale
        types = self.lmp.numpy.extract_atom('type')[:nlocal]
        return self._type_scale[types][:, None]

    def _sorted_canonically(self, x_nc):
        """Whether this rank's atoms sit one to a sort bin, in bin order,
        as LAMMPS's ``Atom::sort`` left them at this setup: then their
        order, and so every sum over them, is a function of positions."""
        lo = np.array(self.lmp.extract_global('sublo'), dtype=float)
        hi = np.array(self.lmp.extract_global('subhi'), dtype=float)
        n_bins = np.maximum(((hi - lo) * (1.0 / self.sort_bin)).astype(int),
                            1)
        index = ((x_nc - lo) * (n_bins / (hi - lo))).astype(np.int64)
        np.clip(index, 0, n_bins - 1, out=index)
        flat = (index[:, 2] * n_bins[1] + index[:, 1]) * n_bins[0] \
            + index[:, 0]
        return bool(np.all(np.diff(flat) > 0))

    def _compare_with_noisy(self, f_clean, tags):
        """Record how far the run's forces at the taken-back step were from
        the clean ones, for the atoms this rank held both times."""
        noisy_tags, f_noisy, bound = self._noisy
        order = np.argsort(noisy_tags)
        where = np.searchsorted(noisy_tags, tags, sorter=order)
        where = np.minimum(where, len(order) - 1)
        held = noisy_tags[order[where]] == tags
        noise = float(np.abs(f_clean[held] - f_noisy[order[where[held]]])
                      .max(initial=0.0))
        self._observed = (noise, bound / self._scale_max)
