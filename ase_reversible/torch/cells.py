"""The canonical neighbour list built on a torch device, cell lists and all.

:class:`TorchNeighbourList` returns, on the device of the model, the same
bits in the same order as
:func:`~ase_reversible.torch.neighbours.neighbour_list` (numpy, on the
host): every ordered pair ``(i, j, S)`` with ``|x_j - x_i + S @ cell| <
cutoff``, sorted by ``(i, j, S)``.  It mirrors the numpy module's search
step for step and calls its rules rather than restating them: the checks,
the margin, the cell's geometry, the images and cubes (host-side, from
the cell and the box the atoms fill), the canonical order
(:func:`~ase_reversible.torch.neighbours.canonical_key`), and the two
pieces of arithmetic that decide the bits,
:func:`~ase_reversible.torch.neighbours.within` (the exact test by which
both lists select their candidates) and
:func:`~ase_reversible.torch.neighbours.image_shifts` (``S @ cell``),
written once for numpy arrays and torch tensors; each eager torch
operation is its own kernel, so nothing is contracted into an FMA on
CUDA.  The search itself only has to find a superset of the pairs (the
margin covers its rounding).  ``tests/test_torch_neighbours.py`` holds
the two lists equal with ``np.array_equal``, on the CPU and, where there
is one, on CUDA.

Per call on a skin hit: one host sync to decide whether any atom moved
more than ``skin / 2`` and one for the number of pairs (``nonzero``),
about twenty kernels, no copy between host and device but the positions
when they come as a numpy array.  A rebuild costs some more syncs (the
box, the number of ghosts, of candidates), none per atom.  The candidates
kept between rebuilds number about ``4.2 (cutoff + skin)^3`` times the
density per atom (``i``, ``j``, ``S`` and the shift: 64 bytes each); the
search passes through about ``15.6 (cutoff + skin)^3`` per atom on the
way (some 50 bytes each, at once).  For 32,000 argon atoms (fcc, a =
5.26 Å) with 8 + 1 Å: 2.5 million candidates kept (160 MB), 9.7 million
passed through.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import torch

from .neighbours import (canonical_key, cell_geometry, check_positions,
                         checked_cell, checked_skin, cube_grid, image_grid,
                         image_shifts, search_margin, within)


class _Search(NamedTuple):
    x_nc: torch.Tensor        # where the candidates were searched, Å
    cell: bytes
    pbc: bytes
    ij_2p: torch.Tensor       # [2, n_candidates] int64, canonical order
    s_pc: torch.Tensor        # [n_candidates, 3] int64, images
    shift_pc: torch.Tensor    # [n_candidates, 3] float64, Å


class TorchNeighbourList:
    """The canonical neighbour list on a torch device, with a skin.

    Parameters
    ----------
    cutoff : float
        Å, positive.
    skin : float
        Å, non-negative.  Candidates are searched within ``cutoff +
        skin`` and kept while no atom has moved more than ``skin / 2``
        from where they were searched (and the cell, pbc and number of
        atoms are the same); each call keeps those strictly inside
        ``cutoff`` by the exact test of the numpy list.
    device : str or torch.device
        Where the positions are read and the pairs are built.
    """

    def __init__(self, cutoff: float, skin: float = 1.0, device='cpu'):
        self.cutoff = float(cutoff)
        self.skin = checked_skin(skin)
        self.device = torch.device(device)
        self._search = None

    def __call__(self, positions, cell, pbc):
        """The pairs of ``positions`` (``[n_atoms, 3]``, Å: a float64
        tensor on the device, or anything ``torch.as_tensor`` takes,
        moved there), ``cell`` (``[3, 3]``, Å, rows, host) and ``pbc``
        (3 bool, host).

        Returns ``(edge_index [2, n_edges] int64, edge_shift [n_edges, 3]
        float64 (Å), image [n_edges, 3] int64)`` on the device: bit for
        bit those of :func:`~ase_reversible.torch.neighbours.neighbour_list`.
        """
        cell, pbc, cutoff = checked_cell(cell, pbc, self.cutoff)
        # Detached: the reference kept for the skin must hold no graph.
        x_nc = torch.as_tensor(positions, dtype=torch.float64,
                               device=self.device).detach()
        # Finiteness is checked on a rebuild only: a NaN or infinite
        # position makes the moved test fail, so it always gets there.
        check_positions(tuple(x_nc.shape), True)
        search = self._search
        if (search is None or len(search.x_nc) != len(x_nc)
                or search.cell != cell.tobytes()
                or search.pbc != pbc.tobytes()
                or self._moved(x_nc, search.x_nc)):
            check_positions(tuple(x_nc.shape),
                            bool(torch.isfinite(x_nc).all()))
            ij_2p, s_pc, shift_pc = sorted_candidates(
                x_nc, cell, pbc, cutoff + self.skin)
            search = self._search = _Search(
                x_nc.clone(), cell.tobytes(), pbc.tobytes(), ij_2p, s_pc,
                shift_pc)
        ends_2pc = x_nc.index_select(0, search.ij_2p.reshape(-1)).view(
            2, -1, 3)
        keep_e = torch.nonzero(within(ends_2pc[0], ends_2pc[1],
                                      search.shift_pc, cutoff)).squeeze(1)
        return (search.ij_2p.index_select(1, keep_e),
                search.shift_pc.index_select(0, keep_e),
                search.s_pc.index_select(0, keep_e))

    def _moved(self, x_nc, ref_nc):
        """Whether an atom moved more than ``skin / 2`` (or is not finite):
        one host sync."""
        if not len(x_nc):
            return False
        d_nc = x_nc - ref_nc
        moved = (d_nc * d_nc).sum(dim=1).max()
        return not moved.item() <= (0.5 * self.skin) ** 2


def sorted_candidates(x_nc, cell, pbc, reach):
    """A superset of the pairs within ``reach`` (Å) of ``x_nc``
    (``[n_atoms, 3]`` float64 tensor) without an atom paired with itself
    in its own cell, in canonical order, on ``x_nc``'s device: ``(ij
    [2, n_candidates] int64, S [n_candidates, 3] int64, S @ cell
    [n_candidates, 3] float64)``; ``cell`` and ``pbc`` as returned by
    :func:`~ase_reversible.torch.neighbours.checked_cell`."""
    device = x_nc.device
    n = len(x_nc)
    if n == 0:
        return _empty(device)
    i_p, j_p, s_pc = _candidates(x_nc, cell, pbc, reach)
    if not len(i_p):
        return _empty(device)
    low, high = torch.stack((s_pc.amin(dim=0), s_pc.amax(dim=0))).tolist()
    key = canonical_key(i_p, j_p, s_pc, n, low, high)
    if key is not None:
        order_p = torch.argsort(key, stable=True)
    else:
        order_p = torch.arange(len(i_p), device=device)
        for column in (s_pc[:, 2], s_pc[:, 1], s_pc[:, 0], j_p, i_p):
            order_p = order_p[torch.argsort(column[order_p], stable=True)]
    s_pc = s_pc.index_select(0, order_p)
    cell_t = torch.as_tensor(cell, dtype=torch.float64, device=device)
    if np.prod([h - lo + 1 for lo, h in zip(low, high)]) < len(s_pc):
        # The shifts of the few distinct images, then gathered:
        # elementwise, so the same bits as over every candidate.
        shift_pc = _shifts_by_table(s_pc, cell_t, low, high)
    else:
        shift_pc = image_shifts(s_pc.to(torch.float64), cell_t)
    return (torch.stack((i_p.index_select(0, order_p),
                         j_p.index_select(0, order_p))), s_pc, shift_pc)


def _shifts_by_table(s_pc, cell, low, high):
    """``image_shifts(s_pc, cell)`` (``cell`` a tensor on ``s_pc``'s
    device) through a table of every image from ``low`` to ``high``
    (``[3]`` ints): elementwise, so the same bits."""
    device = s_pc.device
    low_c = torch.tensor(low, device=device)
    width = [h - lo + 1 for lo, h in zip(low, high)]
    table = torch.cartesian_prod(*[
        torch.arange(lo, h + 1, device=device) for lo, h in zip(low, high)])
    table = image_shifts(table.reshape(-1, 3).to(torch.float64), cell)
    strides = torch.tensor([width[1] * width[2], width[2], 1], device=device)
    return table.index_select(0, ((s_pc - low_c) * strides).sum(dim=1))


def _empty(device):
    return (torch.zeros((2, 0), dtype=torch.int64, device=device),
            torch.zeros((0, 3), dtype=torch.int64, device=device),
            torch.zeros((0, 3), dtype=torch.float64, device=device))


def _candidates(x_nc, cell, pbc, reach):
    """``(i, j, S)`` of a superset of the pairs within ``reach``: the
    numpy module's ``_candidates`` on the device."""
    device = x_nc.device
    n = len(x_nc)
    margin = search_margin(reach)
    geometry = cell_geometry(cell, pbc, margin)
    cell_t = torch.as_tensor(cell, dtype=torch.float64, device=device)
    # Wrap into the cell along the periodic directions; w_nc: by how many
    # cell vectors each atom moved.  The products by the cell go through
    # image_shifts, not @: no cuBLAS call (which deterministic mode
    # refuses on CUDA without its workspace fixed).
    if pbc.any():
        normals = torch.as_tensor(geometry.normals, dtype=torch.float64,
                                  device=device)
        f_nc = image_shifts(x_nc, normals.T)
        periodic = torch.as_tensor(pbc, device=device)
        w_nc = torch.where(periodic, torch.floor(f_nc), 0.0).to(torch.int64)
        xw_nc = x_nc - image_shifts(w_nc.to(torch.float64), cell_t)
        fw_nc = f_nc - w_nc
    else:
        w_nc = torch.zeros((n, 3), dtype=torch.int64, device=device)
        xw_nc = x_nc
    # Ghosts: every atom through each image within reach, kept if within
    # the margin (in fractional terms) of the wrapped cell.
    images = torch.as_tensor(image_grid(geometry.reach), device=device)
    if len(images) > 1:
        keep = torch.ones((len(images), n), dtype=torch.bool, device=device)
        for a in np.flatnonzero(pbc).tolist():
            fa = fw_nc[None, :, a] + images[:, a:a + 1]
            pad = float(geometry.pads[a])
            keep &= (fa > -pad) & (fa < 1 + pad)
        img_k, atom_k = torch.nonzero(keep, as_tuple=True)
        image_kc = images.index_select(0, img_k)
        ghost_kc = (xw_nc.index_select(0, atom_k)
                    + image_shifts(image_kc.to(torch.float64), cell_t))
    else:
        atom_k = torch.arange(n, device=device)
        ghost_kc = xw_nc
        image_kc = torch.zeros((n, 3), dtype=torch.int64, device=device)
    # Cubes over the centres' box grown by the margin; ghosts outside it
    # are too far from every centre.
    box = torch.stack((xw_nc.amin(dim=0), xw_nc.amax(dim=0))).cpu().numpy()
    lo, hi = box[0] - margin, box[1] + margin
    lo_t = torch.as_tensor(lo, device=device)
    hi_t = torch.as_tensor(hi, device=device)
    inside_k = torch.nonzero(((ghost_kc >= lo_t) & (ghost_kc <= hi_t))
                             .all(dim=1)).squeeze(1)
    atom_k, ghost_kc, image_kc = (atom_k[inside_k], ghost_kc[inside_k],
                                  image_kc[inside_k])
    grid = cube_grid(lo, hi, margin, len(atom_k))
    top = torch.as_tensor(grid.dims - 1 - 2 * grid.reach, device=device)
    strides = torch.as_tensor(grid.strides, device=device)

    def cube_of(p_nc):
        c_nc = torch.floor((p_nc - lo_t) / grid.size).to(torch.int64)
        # An integer sum, not a matrix product: CUDA has none for int64.
        return ((torch.minimum(c_nc.clamp(min=0), top) + grid.reach)
                * strides).sum(dim=1)

    # Ghosts sorted by cube, so that each cube's are a contiguous run.
    ghost_cube = cube_of(ghost_kc)
    order = torch.argsort(ghost_cube, stable=True)
    sorted_cube = ghost_cube.index_select(0, order)
    atom_k, ghost_kc, image_kc = (atom_k.index_select(0, order),
                                  ghost_kc.index_select(0, order),
                                  image_kc.index_select(0, order))
    offsets = torch.as_tensor(grid.offsets, device=device)
    near = (cube_of(xw_nc)[:, None] + offsets).reshape(-1)
    # Where each cube's run starts, for every cube of the grid (a few per
    # atom): two gathers per near cube instead of two binary searches.
    run = torch.searchsorted(sorted_cube, torch.arange(
        int(np.prod(grid.dims)) + 1, device=device))
    start = run.index_select(0, near)
    count = run.index_select(0, near + 1) - start
    total = int(count.sum())
    per_atom = count.view(n, len(offsets)).sum(dim=1)
    # Slots start[k], start[k]+1, ..., stop[k]-1 for every k, flat; the
    # centres in order, each as many times as it has slots.
    first = torch.repeat_interleave(start - torch.cumsum(count, 0) + count,
                                    count, output_size=total)
    k = first + torch.arange(total, device=device)
    centre = torch.arange(n, device=device).repeat_interleave(
        per_atom, output_size=total)
    # A first cut by the ghosts' distances, with room for rounding (the
    # exact test follows), and no atom with itself in its own cell.
    r2 = torch.zeros(total, dtype=torch.float64, device=device)
    for a in range(3):   # by columns: contiguous, no [total, 3] temporaries
        d = ghost_kc[:, a].contiguous().index_select(0, k)
        d -= xw_nc[:, a].repeat_interleave(per_atom, output_size=total)
        r2 += d * d
    scale = ghost_kc.abs().max() + xw_nc.abs().max()
    close = r2 < (margin + 1e-12 * scale) ** 2
    del d, r2
    home_k = (image_kc == 0).all(dim=1)
    itself = (atom_k.index_select(0, k) == centre) & home_k.index_select(0, k)
    kept = torch.nonzero(close & ~itself).squeeze(1)
    k, centre = k.index_select(0, kept), centre.index_select(0, kept)
    j = atom_k.index_select(0, k)
    # The true image: ghost = x_j - w_j cell + S' cell, centre = x_i - w_i
    # cell, so the pair vector is x_j - x_i + (S' - w_j + w_i) cell.
    return centre, j, (image_kc.index_select(0, k) - w_nc.index_select(0, j)
                       + w_nc.index_select(0, centre))
