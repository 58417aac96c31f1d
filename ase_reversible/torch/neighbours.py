"""A canonical neighbour list in numpy: a pure function of positions, cell
and pbc.

:func:`neighbour_list` returns every ordered pair ``(i, j, S)`` (atom
``j`` seen through the periodic image ``S``, integers) with
``|x_j - x_i + S @ cell| < cutoff``, both directions, sorted by
``(i, j, S)``.  Same input, same bits in the same order: the pair
distances that decide membership are computed from the given positions
in a fixed order (no BLAS), and the search that proposes candidates only
needs to find a superset of the pairs, sorted.  So :class:`NeighbourList`
can keep its candidates from an earlier search (a skin) and still return
exactly what :func:`neighbour_list` would.

The search bins atoms into cubes a fraction of the cut-off wide, over
the atoms wrapped into the cell plus the periodic images within the
cut-off of it (as many images as a small cell needs, so a cell thinner
than the cut-off is handled, not refused), and compares each atom with
the atoms of the cubes around its own.  Everything is vectorised: no
Python loop over atoms.  Measured against ASE's ``neighbor_list`` in
``benchmarks/torch_products.py`` (docs/benchmarks.md).
"""

from __future__ import annotations

import math

import numpy as np

#: Cubes per cut-off length: 2 gives cubes of rc/2 and 5x5x5 of them
#: around each atom, 15.6 rc^3 of candidates against 27 rc^3 for cubes of
#: rc (the pairs themselves fill 4.2 rc^3).
_CUBES_PER_CUTOFF = 2


def neighbour_list(positions, cell, pbc, cutoff):
    """Pairs strictly inside ``cutoff``, both directions, canonical order.

    Parameters
    ----------
    positions : array ``[n_atoms, 3]``
        Å.
    cell : array ``[3, 3]``
        Å, rows are the cell vectors (ASE's ``atoms.cell``).  Only the
        periodic directions' vectors are used for images; they must be
        independent.
    pbc : array of 3 bool
        Periodic directions.
    cutoff : float
        Å, positive.

    Returns
    -------
    edge_index : int64 array ``[2, n_edges]``
        ``(i, j)`` of each pair, both ``i -> j`` and ``j -> i``; sorted by
        ``i``, then ``j``, then the image.
    edge_shift : float64 array ``[n_edges, 3]``
        Å, such that ``x[j] - x[i] + edge_shift`` is the pair vector.
    image : int64 array ``[n_edges, 3]``
        The image ``S`` of each pair (``edge_shift = S @ cell``, summed in
        a fixed order).
    """
    x_nc, cell, pbc, cutoff = _checked(positions, cell, pbc, cutoff)
    return _select(x_nc, _sorted_candidates(x_nc, cell, pbc, cutoff),
                   cutoff)


class NeighbourList:
    """:func:`neighbour_list` with a skin: the same bits, searched less.

    Parameters
    ----------
    cutoff : float
        Å.
    skin : float
        Å.  Candidates are searched within ``cutoff + skin`` and kept
        while no atom has moved more than ``skin / 2`` from where they
        were searched (and the cell, pbc and number of atoms are the
        same); each call keeps the candidates strictly inside ``cutoff``
        by the same exact test as :func:`neighbour_list`.  The candidates
        are a superset of the pairs and sorted, so the result is that of
        :func:`neighbour_list`, bit for bit, whatever the history.
    """

    def __init__(self, cutoff: float, skin: float = 1.0):
        self.cutoff = float(cutoff)
        self.skin = float(skin)
        if not (math.isfinite(self.skin) and self.skin >= 0):
            raise ValueError(f'The skin must be a non-negative length in Å, '
                             f'got {skin!r}')
        self._search = None   # (positions, cell bytes, pbc bytes, candidates)

    def __call__(self, positions, cell, pbc):
        """``(edge_index, edge_shift, image)`` as :func:`neighbour_list`."""
        x_nc, cell, pbc, cutoff = _checked(positions, cell, pbc, self.cutoff)
        search = self._search
        if (search is None or len(search[0]) != len(x_nc)
                or search[1] != cell.tobytes() or search[2] != pbc.tobytes()
                or _moved_beyond(x_nc, search[0], 0.5 * self.skin)):
            candidates = _sorted_candidates(x_nc, cell, pbc,
                                            cutoff + self.skin)
            search = self._search = (x_nc.copy(), cell.tobytes(),
                                     pbc.tobytes(), candidates)
        return _select(x_nc, search[3], cutoff)


def _moved_beyond(x_nc, ref_nc, distance):
    d_nc = x_nc - ref_nc
    moved_n = d_nc[:, 0] * d_nc[:, 0] + d_nc[:, 1] * d_nc[:, 1] \
        + d_nc[:, 2] * d_nc[:, 2]
    return bool(moved_n.max(initial=0.0) > distance * distance)


def _checked(positions, cell, pbc, cutoff):
    x_nc = np.ascontiguousarray(positions, dtype=np.float64)
    cell = np.ascontiguousarray(cell, dtype=np.float64).reshape(3, 3)
    pbc = np.ascontiguousarray(pbc, dtype=bool).reshape(3)
    cutoff = float(cutoff)
    if not (math.isfinite(cutoff) and cutoff > 0):
        raise ValueError(f'The cut-off must be a positive length in Å, got '
                         f'{cutoff!r}')
    if x_nc.ndim != 2 or x_nc.shape[1] != 3:
        raise ValueError(f'positions must have shape (n_atoms, 3), got '
                         f'{x_nc.shape}')
    if not np.isfinite(x_nc).all():
        raise ValueError('The positions hold NaN or infinite values.')
    return x_nc, cell, pbc, cutoff


def _sorted_candidates(x_nc, cell, pbc, reach):
    """A superset of the pairs within ``reach``, without an atom paired
    with itself in its own cell, sorted by (i, j, S): ``(i, j, S, S @
    cell)``."""
    n = len(x_nc)
    if n == 0:
        return (np.zeros(0, np.int64), np.zeros(0, np.int64),
                np.zeros((0, 3), np.int64), np.zeros((0, 3)))
    i_p, j_p, s_pc = _candidates(x_nc, cell, pbc, reach)
    keep_p = ~((i_p == j_p) & ~s_pc.any(axis=1))
    i_p, j_p, s_pc = i_p[keep_p], j_p[keep_p], s_pc[keep_p]
    order_p = _canonical_order(i_p, j_p, s_pc, n)
    s_pc = s_pc[order_p]
    return i_p[order_p], j_p[order_p], s_pc, _shifts(s_pc, cell)


def _select(x_nc, candidates, cutoff):
    """The candidates strictly inside ``cutoff``, decided from the given
    positions only, by the distance a model computes: (x_j - x_i) + S @
    cell, squared and summed in order.  Keeps their order."""
    i_p, j_p, s_pc, shift_pc = candidates
    d_pc = (x_nc[j_p] - x_nc[i_p]) + shift_pc
    r2_p = d_pc[:, 0] * d_pc[:, 0] + d_pc[:, 1] * d_pc[:, 1] \
        + d_pc[:, 2] * d_pc[:, 2]
    keep_p = r2_p < cutoff * cutoff
    return (np.stack((i_p[keep_p], j_p[keep_p])), shift_pc[keep_p],
            s_pc[keep_p])


def _canonical_order(i_p, j_p, s_pc, n):
    """The permutation sorting by (i, j, S): one sort of a combined
    integer key where it fits in int64, else numpy's lexsort."""
    if not len(i_p):
        return np.zeros(0, np.int64)
    low = s_pc.min(axis=0)
    width = s_pc.max(axis=0) - low + 1
    if float(n) * n * float(np.prod(width.astype(float))) < 2.0**62:
        key = i_p * n + j_p
        for c in range(3):
            key = key * width[c] + (s_pc[:, c] - low[c])
        return np.argsort(key, kind='stable')
    return np.lexsort((s_pc[:, 2], s_pc[:, 1], s_pc[:, 0], j_p, i_p))


def _shifts(s_pc, cell):
    """``S @ cell`` summed in a fixed order (BLAS could change the bits)."""
    s_pc = s_pc.astype(np.float64)
    return (s_pc[:, 0:1] * cell[0] + s_pc[:, 1:2] * cell[1]) \
        + s_pc[:, 2:3] * cell[2]


def _candidates(x_nc, cell, pbc, cutoff):
    """A superset of the pairs within ``cutoff``: ``(i, j, S)``."""
    n = len(x_nc)
    # Wrap into the cell along the periodic directions; remember by how
    # many cell vectors each atom moved (w_nc, integers).
    w_nc = np.zeros((n, 3), np.int64)
    reach_c = np.zeros(3, np.int64)
    margin = cutoff * (1 + 1e-6) + 1e-9
    if pbc.any():
        periodic = np.flatnonzero(pbc)
        vectors = cell[periodic]
        if np.linalg.matrix_rank(vectors) < len(periodic):
            raise ValueError(
                f'The cell vectors of the periodic directions {periodic.tolist()} '
                f'are not independent: {cell.tolist()}. Set a cell with '
                'non-zero, independent vectors along every periodic '
                'direction (atoms.set_cell).')
        full = _complete(cell, pbc)
        # Rows of inv(full).T are the normals: f_a = x . normal_a.
        normals = np.linalg.inv(full).T
        heights = 1.0 / np.linalg.norm(normals, axis=1)
        f_nc = x_nc @ normals.T
        for a in periodic:
            w_nc[:, a] = np.floor(f_nc[:, a]).astype(np.int64)
            reach_c[a] = int(math.ceil(margin / heights[a]))
        xw_nc = x_nc - w_nc.astype(np.float64) @ cell
        fw_nc = f_nc - w_nc
    else:
        xw_nc = x_nc
    # Images: every atom shifted by each S within reach, kept if within
    # the cut-off (in fractional terms) of the wrapped cell.
    ranges = [np.arange(-r, r + 1) for r in reach_c]
    images = np.stack(np.meshgrid(*ranges, indexing='ij'),
                      axis=-1).reshape(-1, 3)
    if len(images) > 1:
        keep = np.ones((len(images), n), bool)
        for a in np.flatnonzero(pbc):
            pad = margin / heights[a]
            fa = fw_nc[None, :, a] + images[:, a:a + 1]
            keep &= (fa > -pad) & (fa < 1 + pad)
        img_k, atom_k = np.nonzero(keep)
        ghost_k = xw_nc[atom_k] + images[img_k].astype(np.float64) @ cell
        image_kc = images[img_k]
    else:
        atom_k = np.arange(n)
        ghost_k = xw_nc
        image_kc = np.zeros((n, 3), np.int64)
    # Cubes over the centres' box grown by the cut-off; ghosts outside it
    # are too far from every centre.
    lo = xw_nc.min(axis=0) - margin
    hi = xw_nc.max(axis=0) + margin
    inside = ((ghost_k >= lo) & (ghost_k <= hi)).all(axis=1)
    atom_k, ghost_k, image_kc = atom_k[inside], ghost_k[inside], \
        image_kc[inside]
    # Cubes no smaller than cutoff / 2, and not more of them than a few
    # per atom (a sparse open system would otherwise allocate a huge grid).
    size = max(margin / _CUBES_PER_CUTOFF,
               (np.prod(hi - lo) / (4.0 * len(ghost_k))) ** (1 / 3))
    reach = int(math.ceil(margin / size))
    dims = np.floor((hi - lo) / size).astype(np.int64) + 1 + 2 * reach
    strides = np.array([dims[1] * dims[2], dims[2], 1], np.int64)

    def cube_of(p):
        c = np.floor((p - lo) / size).astype(np.int64)
        return np.clip(c, 0, dims - 1 - 2 * reach) + reach

    ghost_cube = cube_of(ghost_k) @ strides
    order = np.argsort(ghost_cube, kind='stable')
    sorted_cube = ghost_cube[order]
    centre_cube = cube_of(xw_nc) @ strides
    offsets = np.stack(np.meshgrid(*[np.arange(-reach, reach + 1)] * 3,
                                   indexing='ij'), axis=-1).reshape(-1, 3)
    near = (centre_cube[:, None] + offsets @ strides).ravel()
    start = np.searchsorted(sorted_cube, near, side='left')
    stop = np.searchsorted(sorted_cube, near, side='right')
    count = stop - start
    total = int(count.sum())
    centre = np.repeat(np.repeat(np.arange(n), len(offsets)), count)
    # Positions start[k], start[k]+1, ..., stop[k]-1 for every k, flat.
    first = np.repeat(start - np.cumsum(count) + count, count)
    slot = first + np.arange(total)
    k = order[slot]
    # A first cut by the ghosts' distances (cheap, slightly inexact: the
    # exact test follows on the survivors), with room for rounding.
    d = ghost_k[k] - xw_nc[centre]
    scale = np.abs(ghost_k).max(initial=0.0) + np.abs(xw_nc).max()
    reach2 = (margin + 1e-12 * scale) ** 2
    close = d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1] + d[:, 2] * d[:, 2] \
        < reach2
    k, centre = k[close], centre[close]
    j = atom_k[k]
    # The true image: ghost = x_j - w_j cell + S' cell, centre = x_i - w_i
    # cell, so the pair vector is x_j - x_i + (S' - w_j + w_i) cell.
    s = image_kc[k] - w_nc[j] + w_nc[centre]
    return centre, j, s


def _complete(cell, pbc):
    """The cell with the non-periodic vectors replaced by unit vectors
    orthogonal to the periodic ones (they only serve to invert it)."""
    full = cell.copy()
    periodic = list(np.flatnonzero(pbc))
    if len(periodic) == 3:
        return full
    # An orthonormal basis of the periodic vectors, then completed from
    # the coordinate axes (Gram-Schmidt): the added vectors are
    # orthogonal to the periodic ones.
    basis = []
    for given in [cell[a] for a in periodic] + list(np.eye(3)):
        v = given
        for b in basis:
            v = v - (v @ b) * b
        norm = np.linalg.norm(v)
        if len(basis) < 3 and norm > 1e-6 * np.linalg.norm(given):
            basis.append(v / norm)
    extra = iter(basis[len(periodic):])
    for a in range(3):
        if not pbc[a]:
            full[a] = next(extra)
    return full
