"""The canonical neighbour list of ase_reversible.torch: the set of pairs
(against a brute force and ASE's neighbor_list) and its canonical order."""

import pytest

torch = pytest.importorskip('torch',
                            reason='ase_reversible.torch needs PyTorch')

import itertools  # noqa: E402

import numpy as np  # noqa: E402
from ase import Atoms  # noqa: E402
from ase.neighborlist import neighbor_list as ase_neighbor_list  # noqa: E402

from ase_reversible.torch.neighbours import neighbour_list  # noqa: E402


def brute_force(x_nc, cell, pbc, cutoff):
    """Every (i, j, S) within the cut-off, by trying all images in reach."""
    reach = []
    for a in range(3):
        if pbc[a]:
            normal = np.cross(cell[(a + 1) % 3], cell[(a + 2) % 3])
            height = abs(np.dot(cell[a], normal)) / np.linalg.norm(normal)
            # Atoms may sit outside the cell: reach over their spread too.
            f = x_nc @ np.linalg.inv(cell)
            spread = np.ptp(f[:, a]) if len(f) else 0
            reach.append(int(np.ceil(cutoff / height + spread)) + 1)
        else:
            reach.append(0)
    pairs = set()
    for s in itertools.product(*[range(-r, r + 1) for r in reach]):
        shift = np.array(s, float) @ cell
        d = x_nc[None, :, :] - x_nc[:, None, :] + shift
        r2 = (d * d).sum(axis=2)
        for i, j in zip(*np.nonzero(r2 < cutoff * cutoff)):
            if i != j or any(s):
                pairs.add((int(i), int(j), s))
    return pairs


def as_set(edge_index, image):
    return set(zip(edge_index[0].tolist(), edge_index[1].tolist(),
                   map(tuple, image.tolist())))


def random_system(rng):
    n = int(rng.integers(2, 40))
    pbc = rng.random(3) < 0.6
    cell = np.diag(rng.uniform(2.5, 8, 3))
    if rng.random() < 0.6:          # triclinic
        cell = cell + np.triu(rng.uniform(-1.5, 1.5, (3, 3)), 1)
    # Some atoms outside the cell, as MD leaves them.
    x_nc = rng.uniform(-0.3, 1.3, (n, 3)) @ cell
    return x_nc, cell, pbc, float(rng.uniform(1.5, 6.0))


@pytest.mark.parametrize('seed', range(12))
def test_pairs_are_those_of_a_brute_force_and_of_ase(seed):
    rng = np.random.default_rng(seed)
    x_nc, cell, pbc, cutoff = random_system(rng)
    edge_index, edge_shift, image = neighbour_list(x_nc, cell, pbc, cutoff)
    got = as_set(edge_index, image)
    assert len(got) == edge_index.shape[1]          # no duplicates
    assert got == brute_force(x_nc, cell, pbc, cutoff)
    atoms = Atoms(f'H{len(x_nc)}', positions=x_nc, cell=cell, pbc=pbc)
    i, j, s = ase_neighbor_list('ijS', atoms, cutoff)
    assert got == set(zip(i.tolist(), j.tolist(), map(tuple, s.tolist())))
    # Both directions, shifts that give the pair vectors.
    assert got == {(j, i, tuple(-np.array(s))) for i, j, s in got}
    assert np.array_equal(edge_shift, image.astype(float) @ cell) or \
        np.allclose(edge_shift, image @ cell, rtol=0, atol=1e-12)
    d = x_nc[edge_index[1]] - x_nc[edge_index[0]] + edge_shift
    assert (np.sqrt((d * d).sum(axis=1)) < cutoff).all()


def test_a_cell_thinner_than_the_cutoff_gets_several_images():
    cell = np.array([[2.0, 0, 0], [0.7, 2.2, 0], [0, 0, 9.0]])
    x_nc = np.array([[0.1, 0.2, 0.3], [1.0, 1.1, 4.0]])
    pbc = np.array([True, True, False])
    edge_index, _, image = neighbour_list(x_nc, cell, pbc, 5.0)
    got = as_set(edge_index, image)
    assert got == brute_force(x_nc, cell, pbc, 5.0)
    assert max(abs(s[0]) for _, _, s in got) >= 2


def test_order_is_canonical_and_the_bits_repeat():
    rng = np.random.default_rng(7)
    x_nc, cell, pbc, cutoff = random_system(rng)
    pbc[:] = True
    first = neighbour_list(x_nc, cell, pbc, cutoff)
    i, j = first[0]
    s = first[2]
    keys = np.lexsort((s[:, 2], s[:, 1], s[:, 0], j, i))
    assert np.array_equal(keys, np.arange(len(i)))
    # Same input after other calls: same bits, same order.
    neighbour_list(x_nc + 0.3, cell, pbc, cutoff)
    again = neighbour_list(x_nc.copy(), cell, pbc, cutoff)
    for a, b in zip(first, again):
        assert a.dtype == b.dtype and np.array_equal(a, b)
    assert first[0].dtype == np.int64 and first[1].dtype == np.float64


def test_open_system_far_apart_and_bad_input():
    x_nc = np.array([[0.0, 0, 0], [1e4, 0, 0], [1e4 + 1.0, 0, 0]])
    edge_index, _, _ = neighbour_list(x_nc, np.zeros((3, 3)), [False] * 3,
                                      2.0)
    assert edge_index.tolist() == [[1, 2], [2, 1]]
    with pytest.raises(ValueError, match='positive length'):
        neighbour_list(x_nc, np.zeros((3, 3)), [False] * 3, 0.0)
    with pytest.raises(ValueError, match='not independent'):
        neighbour_list(x_nc, np.zeros((3, 3)), [True, False, False], 2.0)
    with pytest.raises(ValueError, match='NaN'):
        neighbour_list(x_nc * np.nan, np.zeros((3, 3)), [False] * 3, 2.0)


def test_a_skin_changes_no_bit_of_the_list():
    from ase_reversible.torch.neighbours import NeighbourList
    rng = np.random.default_rng(11)
    x_nc, cell, pbc, cutoff = random_system(rng)
    pbc[:2] = True
    listing = NeighbourList(cutoff, skin=0.8)
    for step in range(12):
        if step == 6:
            x_nc = x_nc + cell[0]            # wrapped by a whole cell
        elif step == 9:
            cell = cell * 1.01               # a new cell
        else:
            x_nc = x_nc + rng.normal(0.0, 0.15, x_nc.shape)
        got = listing(x_nc, cell, pbc)
        expected = neighbour_list(x_nc, cell, pbc, cutoff)
        for a, b in zip(got, expected):
            assert a.dtype == b.dtype and np.array_equal(a, b)
    with pytest.raises(ValueError, match='skin'):
        NeighbourList(cutoff, skin=-1.0)


# The list built by torch, on any device: the same bits in the same order.

DEVICES = ['cpu', pytest.param('cuda', marks=pytest.mark.skipif(
    not torch.cuda.is_available(),
    reason='the CUDA build of the list needs a CUDA device'))]


def assert_same_as_numpy(listing, x_nc, cell, pbc, positions=None):
    """``listing``'s pairs equal, bit for bit, a fresh numpy list's."""
    if positions is None:
        positions = torch.tensor(x_nc, device=listing.device)
    got = listing(positions, cell, pbc)
    expected = neighbour_list(x_nc, cell, pbc, listing.cutoff)
    assert len(got) == len(expected)
    for a, b in zip(got, expected):
        assert a.device == listing.device
        a = a.cpu().numpy()
        assert a.dtype == b.dtype and np.array_equal(a, b)


@pytest.mark.parametrize('device', DEVICES)
@pytest.mark.parametrize('seed', range(12))
def test_the_torch_list_is_the_numpy_list(device, seed):
    from ase_reversible.torch import TorchNeighbourList
    rng = np.random.default_rng(seed)
    x_nc, cell, pbc, cutoff = random_system(rng)
    assert_same_as_numpy(TorchNeighbourList(cutoff, 0.5, device), x_nc,
                         cell, pbc)
    # Numpy positions are moved to the device.
    assert_same_as_numpy(TorchNeighbourList(cutoff, 0.0, device), x_nc,
                         cell, pbc, positions=x_nc)
    # Positions a model differentiates: the list keeps no graph.
    listing = TorchNeighbourList(cutoff, 1.0, device)
    assert_same_as_numpy(listing, x_nc, cell, pbc, positions=torch.tensor(
        x_nc, device=device, requires_grad=True))
    assert not listing._search.x_nc.requires_grad


@pytest.mark.parametrize('device', DEVICES)
def test_the_torch_list_on_thin_cells_open_and_tiny_systems(device):
    from ase_reversible.torch import TorchNeighbourList
    thin = np.array([[2.0, 0, 0], [0.7, 2.2, 0], [0, 0, 9.0]])
    two = np.array([[0.1, 0.2, 0.3], [1.0, 1.1, 4.0]])
    far = np.array([[0.0, 0, 0], [1e4, 0, 0], [1e4 + 1.0, 0, 0]])
    for x_nc, cell, pbc, cutoff in [
            (two, thin, [True, True, False], 5.0),
            (two, thin, [True] * 3, 9.5),
            (far, np.zeros((3, 3)), [False] * 3, 2.0),
            (np.zeros((0, 3)), thin, [True] * 3, 3.0),
            (np.zeros((0, 3)), np.zeros((3, 3)), [False] * 3, 3.0),
            (two[:1], thin, [True] * 3, 4.0),
            (two[:1], np.zeros((3, 3)), [False] * 3, 4.0)]:
        assert_same_as_numpy(TorchNeighbourList(cutoff, 1.0, device), x_nc,
                             thin if cell is thin else cell, np.array(pbc))


@pytest.mark.parametrize('device', DEVICES)
def test_a_skin_history_changes_no_bit_of_the_torch_list(device):
    from ase_reversible.torch import TorchNeighbourList
    rng = np.random.default_rng(11)
    x_nc, cell, pbc, cutoff = random_system(rng)
    pbc[:2] = True
    skin = 0.8
    listing = TorchNeighbourList(cutoff, skin, device)
    rebuilds = 0
    for step in range(16):
        if step == 6:
            x_nc = x_nc + cell[0]            # wrapped by a whole cell
        elif step == 9:
            cell = cell * 1.01               # a new cell
        elif step == 12:
            x_nc = x_nc[:-1]                 # an atom fewer
        else:                                # moves below and above skin/2
            x_nc = x_nc + rng.normal(0.0, (0.02, 0.3)[step % 2],
                                     x_nc.shape)
        before = listing._search
        assert_same_as_numpy(listing, x_nc, cell, pbc)
        rebuilds += listing._search is not before
    assert 3 < rebuilds < 16          # both paths taken


@pytest.mark.parametrize('device', DEVICES)
def test_the_torch_list_runs_under_deterministic_kernels(device):
    # The calculator calls its model in that mode, where PyTorch refuses
    # the operations that have no deterministic kernel.
    from ase_reversible.core.kernels import deterministic_kernels
    from ase_reversible.torch import TorchNeighbourList
    x_nc, cell, pbc, cutoff = random_system(np.random.default_rng(3))
    pbc[:] = True
    with deterministic_kernels():
        assert_same_as_numpy(TorchNeighbourList(cutoff, 1.0, device), x_nc,
                             cell, pbc)


@pytest.mark.parametrize('device', DEVICES)
def test_the_torch_list_refuses_what_the_numpy_list_refuses(device):
    from ase_reversible.torch import TorchNeighbourList
    x_nc = np.array([[0.0, 0, 0], [1e4, 0, 0], [1e4 + 1.0, 0, 0]])
    open_ = (np.zeros((3, 3)), [False] * 3)
    with pytest.raises(ValueError, match='positive length'):
        TorchNeighbourList(0.0, device=device)(x_nc, *open_)
    with pytest.raises(ValueError, match='not independent'):
        TorchNeighbourList(2.0, device=device)(
            x_nc, np.zeros((3, 3)), [True, False, False])
    with pytest.raises(ValueError, match='shape'):
        TorchNeighbourList(2.0, device=device)(x_nc[:, :2], *open_)
    with pytest.raises(ValueError, match='skin'):
        TorchNeighbourList(2.0, skin=-1.0, device=device)
    # NaN or infinite positions, on a fresh list and after a skin hit.
    listing = TorchNeighbourList(2.0, device=device)
    listing(x_nc, *open_)
    for bad in (np.nan, np.inf):
        for fresh in (TorchNeighbourList(2.0, device=device), listing):
            x = torch.tensor(x_nc, device=device)
            x[1, 2] = bad
            with pytest.raises(ValueError, match='NaN or infinite'):
                fresh(x, *open_)
    assert_same_as_numpy(listing, x_nc, *open_)
