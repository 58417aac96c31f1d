"""PyTorch energy models as exact, differentiable ASE calculators.

``import ase_reversible.torch`` needs PyTorch; ``import ase_reversible``
never imports it.  What is here:

- :class:`TorchCalculator`: wraps any ``torch.nn.Module`` whose
  ``forward(positions, numbers, cell, edge_index, edge_shift)`` returns the
  energy; forces that are a pure function of the positions, so
  :class:`~ase_reversible.ReversibleVerlet` runs it out and back bit for
  bit, and one double-backward pass per kick for the reversible adjoint;
- :func:`neighbour_list`: the canonical list it hands to the model;
- :class:`TorchNeighbourList`: the same list, bit for bit, built on the
  model's torch device;
- :class:`PairMLP` and :class:`LennardJones`: two ready models.

See docs/torch.md.
"""

try:
    import torch  # noqa: F401
except ImportError as error:   # pragma: no cover - depends on the venv
    raise ImportError(
        "ase_reversible.torch needs PyTorch: pip install 'torch==2.13.0' "
        "(pip's default torch on Linux is a CUDA build of about 3 GB; for "
        "the CPU build add --index-url https://download.pytorch.org/whl/cpu)"
    ) from error

from ..core.kernels import prepare_cublas

# Before the script's first CUDA call, which usually follows this import:
# cuBLAS reads its workspace setting once, and deterministic kernels need
# it fixed (core/kernels.py).  A value the user set is kept.
prepare_cublas()

from .calculator import TorchCalculator  # noqa: E402
from .cells import TorchNeighbourList  # noqa: E402
from .models import LennardJones, PairMLP  # noqa: E402
from .neighbours import neighbour_list  # noqa: E402

__all__ = ['TorchCalculator', 'PairMLP', 'LennardJones', 'neighbour_list',
           'TorchNeighbourList']
