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

:class:`~ase_reversible.torch.cells.TorchNeighbourList` is the same list
built on a torch device.  The rules both follow have one owner, here:
the checks (:func:`checked_cell`, :func:`check_positions`,
:func:`checked_skin`), the host-side geometry of the search
(:func:`search_margin`, :func:`cell_geometry`, :func:`image_grid`,
:func:`cube_grid`), the canonical order (:func:`canonical_key`) and the
arithmetic that decides the bits, :func:`image_shifts` and
:func:`within`, written once for numpy arrays and torch tensors alike
(each eager torch operation is its own kernel, so no contraction into
FMAs changes a bit).  ``tests/test_torch_neighbours.py`` holds the two
lists equal, bit for bit.
"""

from __future__ import annotations

import math
from typing import NamedTuple

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
    cell, pbc, cutoff = checked_cell(cell, pbc, cutoff)
    x_nc = _checked_positions(positions)
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
        self.skin = checked_skin(skin)
        self._search = None   # (positions, cell bytes, pbc bytes, candidates)

    def __call__(self, positions, cell, pbc):
        """``(edge_index, edge_shift, image)`` as :func:`neighbour_list`."""
        cell, pbc, cutoff = checked_cell(cell, pbc, self.cutoff)
        x_nc = _checked_positions(positions)
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


def checked_cell(cell, pbc, cutoff):
    """``(cell [3, 3] float64, pbc [3] bool, cutoff float)`` as the lists
    use them; ``ValueError`` for a cut-off that is not a positive length
    (Å)."""
    cell = np.ascontiguousarray(cell, dtype=np.float64).reshape(3, 3)
    pbc = np.ascontiguousarray(pbc, dtype=bool).reshape(3)
    cutoff = float(cutoff)
    if not (math.isfinite(cutoff) and cutoff > 0):
        raise ValueError(f'The cut-off must be a positive length in Å, got '
                         f'{cutoff!r}')
    return cell, pbc, cutoff


def checked_skin(skin):
    """The skin as a float (Å); ``ValueError`` unless a non-negative
    length."""
    skin = float(skin)
    if not (math.isfinite(skin) and skin >= 0):
        raise ValueError(f'The skin must be a non-negative length in Å, '
                         f'got {skin!r}')
    return skin


def check_positions(shape, finite):
    """``ValueError`` unless the positions' ``shape`` is ``(n_atoms, 3)``
    and they are all ``finite`` (a bool the caller computed)."""
    if len(shape) != 2 or shape[1] != 3:
        raise ValueError(f'positions must have shape (n_atoms, 3), got '
                         f'{tuple(shape)}')
    if not finite:
        raise ValueError('The positions hold NaN or infinite values.')


def _checked_positions(positions):
    x_nc = np.ascontiguousarray(positions, dtype=np.float64)
    check_positions(x_nc.shape, bool(np.isfinite(x_nc).all()))
    return x_nc


def search_margin(reach):
    """Å: how far the search looks for pairs within ``reach`` (Å): a
    little further, so that rounding in the wrapped positions and the
    ghosts cannot lose a pair (the exact test follows)."""
    return reach * (1 + 1e-6) + 1e-9


class CellGeometry(NamedTuple):
    """What the search needs of a cell (:func:`cell_geometry`)."""
    #: ``[3, 3]``, 1/Å: row ``a`` gives the fractional coordinate ``f_a =
    #: x . normals[a]`` (the non-periodic directions completed).
    normals: np.ndarray
    #: ``[3]``, fractional: the margin over each periodic direction's
    #: height (0 where open).
    pads: np.ndarray
    #: ``[3]`` int64: images on each side within the margin (0 where open).
    reach: np.ndarray


def cell_geometry(cell, pbc, margin):
    """The :class:`CellGeometry` of ``cell`` (Å, rows) for a search to
    ``margin`` (Å, :func:`search_margin`).  ``ValueError`` when the
    periodic directions' vectors are not independent."""
    periodic = np.flatnonzero(pbc)
    if np.linalg.matrix_rank(cell[periodic]) < len(periodic):
        raise ValueError(
            f'The cell vectors of the periodic directions {periodic.tolist()} '
            f'are not independent: {cell.tolist()}. Set a cell with '
            'non-zero, independent vectors along every periodic '
            'direction (atoms.set_cell).')
    normals = np.linalg.inv(_complete(cell, pbc)).T
    heights = 1.0 / np.linalg.norm(normals, axis=1)
    pads = np.where(pbc, margin / heights, 0.0)
    reach = np.where(pbc, np.ceil(pads), 0).astype(np.int64)
    return CellGeometry(normals, pads, reach)


def image_grid(reach_c):
    """``[n_images, 3]`` int64: every image ``S`` with ``|S_a| <=
    reach_c[a]``, ``S`` in lexicographic order."""
    ranges = [np.arange(-r, r + 1) for r in reach_c]
    return np.stack(np.meshgrid(*ranges, indexing='ij'),
                    axis=-1).reshape(-1, 3)


class CubeGrid(NamedTuple):
    """The cubes the search bins into (:func:`cube_grid`)."""
    size: float          #: Å, a cube's edge
    reach: int           #: cubes searched on each side of an atom's own
    dims: np.ndarray     #: ``[3]`` int64, cubes along each axis, padded
    strides: np.ndarray  #: ``[3]`` int64, a cube's flat index = c @ strides
    offsets: np.ndarray  #: ``[(2 reach + 1)^3]`` int64, flat offsets


def cube_grid(lo, hi, margin, n_ghosts):
    """The :class:`CubeGrid` over the box ``lo``..``hi`` (Å, ``[3]``)
    holding ``n_ghosts`` atoms and images, for a search to ``margin``:
    cubes no smaller than ``margin / _CUBES_PER_CUTOFF``, and not more of
    them than a few per atom (a sparse open system would otherwise
    allocate a huge grid)."""
    size = max(margin / _CUBES_PER_CUTOFF,
               (np.prod(hi - lo) / (4.0 * max(n_ghosts, 1))) ** (1 / 3))
    reach = int(math.ceil(margin / size))
    dims = np.floor((hi - lo) / size).astype(np.int64) + 1 + 2 * reach
    strides = np.array([dims[1] * dims[2], dims[2], 1], np.int64)
    offsets = image_grid([reach] * 3) @ strides
    return CubeGrid(float(size), reach, dims, strides, offsets)


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
    return (i_p[order_p], j_p[order_p], s_pc,
            image_shifts(s_pc.astype(np.float64), cell))


def _select(x_nc, candidates, cutoff):
    """The candidates strictly inside ``cutoff``, decided from the given
    positions only, by the distance a model computes: (x_j - x_i) + S @
    cell, squared and summed in order.  Keeps their order."""
    i_p, j_p, s_pc, shift_pc = candidates
    keep_p = within(x_nc[i_p], x_nc[j_p], shift_pc, cutoff)
    return (np.stack((i_p[keep_p], j_p[keep_p])), shift_pc[keep_p],
            s_pc[keep_p])


def within(xi_pc, xj_pc, shift_pc, cutoff):
    """``[n_pairs]`` bool: the pairs strictly inside ``cutoff`` (Å), from
    the positions of their ends (``[n_pairs, 3]``, Å, gathered as the
    caller likes) by the distance a model computes: ``d = (x_j - x_i) +
    shift``, then
    ``d0 d0 + d1 d1 + d2 d2`` in that order, against ``cutoff**2``.  One
    owner for numpy arrays and torch tensors: the same operations in the
    same order, so the same bits on any device."""
    d_pc = (xj_pc - xi_pc) + shift_pc
    r2_p = d_pc[:, 0] * d_pc[:, 0] + d_pc[:, 1] * d_pc[:, 1] \
        + d_pc[:, 2] * d_pc[:, 2]
    return r2_p < cutoff * cutoff


def image_shifts(s_pc, cell):
    """``[n_pairs, 3]``, Å: ``S @ cell`` as ``(S0 c0 + S1 c1) + S2 c2``
    (a matrix product could change the bits), for float64 ``s_pc`` and
    ``cell`` both numpy arrays or both torch tensors on one device."""
    return (s_pc[:, 0:1] * cell[0] + s_pc[:, 1:2] * cell[1]) \
        + s_pc[:, 2:3] * cell[2]


def canonical_key(i_p, j_p, s_pc, n, low, high):
    """``[n_pairs]`` int64 whose order is that of ``(i, j, S)``, for
    numpy arrays or torch tensors; ``None`` when it would not fit in
    int64 (sort by the five columns then).  ``low``, ``high``: ``[3]``
    ints, the least and greatest ``S`` along each axis."""
    width = [int(h) - int(lo) + 1 for lo, h in zip(low, high)]
    if float(n) * n * float(np.prod(np.array(width, float))) >= 2.0**62:
        return None
    key = i_p * n + j_p
    for c in range(3):
        key = key * width[c] + (s_pc[:, c] - int(low[c]))
    return key


def _canonical_order(i_p, j_p, s_pc, n):
    """The permutation sorting by (i, j, S)."""
    if not len(i_p):
        return np.zeros(0, np.int64)
    key = canonical_key(i_p, j_p, s_pc, n, s_pc.min(axis=0),
                        s_pc.max(axis=0))
    if key is not None:
        return np.argsort(key, kind='stable')
    return np.lexsort((s_pc[:, 2], s_pc[:, 1], s_pc[:, 0], j_p, i_p))


def _candidates(x_nc, cell, pbc, cutoff):
    """A superset of the pairs within ``cutoff``: ``(i, j, S)``."""
    n = len(x_nc)
    margin = search_margin(cutoff)
    geometry = cell_geometry(cell, pbc, margin)
    # Wrap into the cell along the periodic directions; remember by how
    # many cell vectors each atom moved (w_nc, integers).
    w_nc = np.zeros((n, 3), np.int64)
    if pbc.any():
        f_nc = x_nc @ geometry.normals.T
        w_nc[:, pbc] = np.floor(f_nc[:, pbc]).astype(np.int64)
        xw_nc = x_nc - w_nc.astype(np.float64) @ cell
        fw_nc = f_nc - w_nc
    else:
        xw_nc = x_nc
    # Images: every atom shifted by each S within reach, kept if within
    # the cut-off (in fractional terms) of the wrapped cell.
    images = image_grid(geometry.reach)
    if len(images) > 1:
        keep = np.ones((len(images), n), bool)
        for a in np.flatnonzero(pbc):
            fa = fw_nc[None, :, a] + images[:, a:a + 1]
            keep &= (fa > -geometry.pads[a]) & (fa < 1 + geometry.pads[a])
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
    grid = cube_grid(lo, hi, margin, len(ghost_k))

    def cube_of(p):
        c = np.floor((p - lo) / grid.size).astype(np.int64)
        return (np.clip(c, 0, grid.dims - 1 - 2 * grid.reach)
                + grid.reach) @ grid.strides

    ghost_cube = cube_of(ghost_k)
    order = np.argsort(ghost_cube, kind='stable')
    sorted_cube = ghost_cube[order]
    near = (cube_of(xw_nc)[:, None] + grid.offsets).ravel()
    start = np.searchsorted(sorted_cube, near, side='left')
    stop = np.searchsorted(sorted_cube, near, side='right')
    count = stop - start
    total = int(count.sum())
    centre = np.repeat(np.repeat(np.arange(n), len(grid.offsets)), count)
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
