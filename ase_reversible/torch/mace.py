"""MACE models (the ``mace-torch`` package) as TorchCalculator models.

:class:`MACEModel` wraps a ``mace.modules.MACE`` (or ``ScaleShiftMACE``)
in the ``forward(positions, numbers, cell, edge_index, edge_shift)``
signature of :class:`~ase_reversible.torch.TorchCalculator`, so a MACE
model runs out and back bit for bit and the reversible adjoint
differentiates through it, weights included.  ``mace-torch`` is not a
dependency: import this module only where it is installed.

Tried here with mace-torch 0.3.16 and e3nn 0.4.4 on PyTorch 2.13.0 (CPU,
float64, random weights; tests/test_torch.py skips without them).  Loading
a saved MACE model with torch >= 2.6 needs
``TORCH_FORCE_NO_WEIGHTS_ONLY_LOAD=1`` (or ``torch.load(...,
weights_only=False)``) for a file you trust; the model must then be made
float64 (``model.double()``) before it is wrapped.
"""

from __future__ import annotations

import torch


class MACEModel(torch.nn.Module):
    """A MACE model as a TorchCalculator model.

    Parameters
    ----------
    model : torch.nn.Module
        A ``mace.modules.MACE`` (or subclass), float64, single head.
    atomic_numbers : sequence of int
        The model's elements in the order of its one-hot node attributes
        (``model.atomic_numbers`` if omitted).

    ``cutoff`` is the model's ``r_max`` (Å): give the calculator the same.
    MACE's edges run from ``edge_index[0]`` (sender) to ``edge_index[1]``
    (receiver) with ``x_receiver - x_sender + shift``, the convention of
    :func:`~ase_reversible.torch.neighbour_list`.
    """

    def __init__(self, model, atomic_numbers=None):
        super().__init__()
        self.model = model
        if atomic_numbers is None:
            atomic_numbers = [int(z) for z in model.atomic_numbers]
        self.register_buffer('atomic_numbers', torch.tensor(
            list(atomic_numbers), dtype=torch.int64))
        self.cutoff = float(model.r_max)

    def forward(self, positions, numbers, cell, edge_index, edge_shift):
        """The energy (eV): MACE's ``'energy'`` of the one graph."""
        n = positions.shape[0]
        match = numbers[:, None] == self.atomic_numbers[None, :]
        if not bool(match.any(dim=1).all()):
            missing = sorted(set(numbers.tolist())
                             - set(self.atomic_numbers.tolist()))
            raise ValueError(f'The MACE model has no element {missing}; it '
                             f'knows {self.atomic_numbers.tolist()}.')
        data = {
            'positions': positions,
            'node_attrs': match.to(positions.dtype),
            'edge_index': edge_index,
            'shifts': edge_shift,
            # Integer images enter only virials and stress, not asked for.
            'unit_shifts': torch.zeros_like(edge_shift),
            'cell': cell.reshape(3, 3),
            'batch': torch.zeros(n, dtype=torch.int64, device=positions.device),
            'ptr': torch.tensor([0, n], dtype=torch.int64,
                                device=positions.device),
        }
        out = self.model(data, training=False, compute_force=False)
        return out['energy'].sum()


def random_mace(atomic_numbers=(29,), r_max: float = 5.0, seed: int = 0):
    """A small ``mace.modules.ScaleShiftMACE`` with random weights, float64.

    Two interactions, 8 scalar and 8 vector channels, correlation order 2,
    ``max_ell`` 2, Bessel radial basis of 8 (23,872 parameters for one
    element).  For trying the
    exact machinery without a trained model (no file to download); save it
    with ``torch.save`` for MACE's own ``MACECalculator(model_paths=...)``.
    ``atomic_numbers``: the elements it knows; ``r_max``: its cut-off, Å;
    ``seed``: ``torch.manual_seed`` before the weights are drawn (the
    global generator's state is restored after).
    """
    import numpy as np
    from e3nn import o3
    from mace import modules
    state = torch.random.get_rng_state()
    torch.manual_seed(seed)
    try:
        block = modules.interaction_classes[
            'RealAgnosticResidualInteractionBlock']
        return modules.ScaleShiftMACE(
            r_max=float(r_max), num_bessel=8, num_polynomial_cutoff=6,
            max_ell=2, interaction_cls=block, interaction_cls_first=block,
            num_interactions=2, num_elements=len(atomic_numbers),
            hidden_irreps=o3.Irreps('8x0e + 8x1o'),
            MLP_irreps=o3.Irreps('8x0e'), gate=torch.nn.functional.silu,
            atomic_energies=np.zeros(len(atomic_numbers)),
            avg_num_neighbors=8.0, atomic_numbers=list(atomic_numbers),
            correlation=2, atomic_inter_scale=1.0,
            atomic_inter_shift=0.0).double()
    finally:
        torch.random.set_rng_state(state)
