"""Where a run back must land: the anchor each atom carries with it, and a
gather of the whole system for tests."""

from __future__ import annotations

import numpy as np


class Anchor:
    """The anchor and the gather of :class:`~.integrator.ReversibleLammps`
    (a part of it: it uses its grid and box)."""

    def mark_anchor(self):
        """Keep every atom's exact state beside it, as a per-atom array that
        migrates with the atom: :meth:`compare_with_anchor` then needs no
        gather.  Collective."""
        if not self._anchor_defined:
            self.lmp.command(f'fix {self.name}_anchor all property/atom '
                             f'd2_{self.name}_anchor 6 ghost no')
            self._anchor_defined = True
        if self.velocity_quantum is None:
            try:
                dt = self._timestep()
            except ValueError:  # set later: the first run snaps the anchor
                dt = None
            if dt is not None:
                self._snap_box()
                self._choose_grid(dt)
        if self.velocity_quantum is not None:
            self._snap_atoms()
        self._anchor_off_grid = self.velocity_quantum is None
        anchor, x_u, v = self._anchor_views()
        anchor[:, :3] = x_u
        anchor[:, 3:] = v

    def compare_with_anchor(self):
        """``(atoms_off, largest_difference)`` over every rank: how many
        atoms' unwrapped positions or velocities differ from the anchor in
        any bit, and by how much at most.  Collective."""
        if not self._anchor_defined:
            raise RuntimeError('no anchor: call mark_anchor() first')
        anchor, x_u, v = self._anchor_views()
        off = np.any(anchor[:, :3] != x_u, axis=1) \
            | np.any(anchor[:, 3:] != v, axis=1)
        largest = max(float(np.abs(anchor[:, :3] - x_u).max(initial=0.0)),
                      float(np.abs(anchor[:, 3:] - v).max(initial=0.0)))
        count = self.world.sum(off.sum())[0]
        return int(count), float(self.world.max(largest)[0])

    def _anchor_views(self):
        lmp = self.lmp
        nlocal = lmp.extract_setting('nlocal')
        anchor = lmp.numpy.extract_atom(f'd2_{self.name}_anchor')[:nlocal]
        x = lmp.numpy.extract_atom('x')[:nlocal]
        v = lmp.numpy.extract_atom('v')[:nlocal]
        return anchor, x + self._images(nlocal) * self._period(), v

    def _images(self, nlocal):
        """Image flags ``[n, 3]`` unpacked from LAMMPS's packed integers."""
        lmp = self.lmp
        packed = np.asarray(lmp.numpy.extract_atom('image')[:nlocal],
                            dtype=np.int64)
        bits = lmp.extract_setting('IMGBITS')
        mask = lmp.extract_setting('IMGMASK')
        middle = lmp.extract_setting('IMGMAX')
        return np.stack([((packed >> (bits * axis)) & mask) - middle
                         for axis in range(3)], axis=1)

    def _period(self):
        lo, hi = self._box()
        return hi - lo

    def gather(self):
        """``(ids, x, v)`` of every atom, ordered by id, on every rank:
        ``x`` unwrapped by the image flags (exact on the grid).  A
        collective copy of the whole system, for tests and small systems."""
        lmp = self.lmp
        n = int(lmp.get_natoms())
        ids = np.ctypeslib.as_array(lmp.gather_atoms('id', 0, 1)).copy()
        x = np.ctypeslib.as_array(lmp.gather_atoms('x', 1, 3)).reshape(n, 3)
        v = np.ctypeslib.as_array(lmp.gather_atoms('v', 1, 3)).reshape(n, 3)
        image = np.ctypeslib.as_array(
            lmp.gather_atoms('image', 0, 3)).reshape(n, 3)
        lo, hi = self._box()
        x = x + image * (hi - lo)
        order = np.argsort(ids)
        return ids[order], x[order], v[order].copy()
