"""Deterministic PyTorch kernels around a call, the caller's settings
restored after it.

A GPU sums with atomic adds whose order changes from call to call, so a
torch model's forces at the same positions differ in the last bits:
MACE's ASE calculator on an NVIDIA H200 (PyTorch 2.11, CUDA 13, float64)
gave 7 distinct force arrays in 13 calls at identical positions, up to
1.1e-17 eV/Å apart, and in float32 up to 5e-9 eV/Å.  Under
``torch.use_deterministic_algorithms(True)`` the same calls gave the same
bits every time, in both precisions, for +6% per force call at 6,912
atoms (397 against 374 ms).  On CUDA that mode also needs cuBLAS's
workspace fixed (``CUBLAS_WORKSPACE_CONFIG``, read when cuBLAS first
makes its workspace): PyTorch refuses a cuBLAS call in deterministic mode
without it.

TorchScript adds a history of its own, and for the whole process: its
graph executor profiles the first calls of a scripted function at each
input shape, then runs an optimised graph with other last bits.  MACE's
ASE calculator (e3nn's scripted tensor products, CPU) gave one result at
the first call and another at every later one at the same positions; and
once any call had run optimised, calls inside
``torch.jit.optimized_execution(False)`` gave other bits than before it
(5 of 6 positions, float32), so no hold around our own calls alone can
fix it.  With the optimisation off for the process, before or after the
model had run optimised, every call gave the same bits (6 positions, 4
rounds), and a call took 48 against 88 ms (float64) and 37 against 69 ms
(float32) for 32 copper atoms on the CPU.

Nothing here imports torch until it is used; only the callers that hold
torch models reach it.
"""

from __future__ import annotations

import contextlib
import os

#: The environment variable cuBLAS reads for its workspace, and the values
#: with which NVIDIA documents its results as reproducible.
CUBLAS_VARIABLE = 'CUBLAS_WORKSPACE_CONFIG'
CUBLAS_DETERMINISTIC = (':4096:8', ':16:8')


def prepare_cublas(environ=None) -> bool:
    """Fix cuBLAS's workspace for deterministic kernels unless the user
    chose a value: ``CUBLAS_WORKSPACE_CONFIG=:4096:8`` if it is unset.

    Returns whether the value now set is one of
    ``CUBLAS_DETERMINISTIC``.  Called when ``ase_reversible.torch`` is
    imported, which a script does before it moves a model to the GPU.
    """
    environ = os.environ if environ is None else environ
    value = environ.setdefault(CUBLAS_VARIABLE, CUBLAS_DETERMINISTIC[0])
    return value in CUBLAS_DETERMINISTIC


def cublas_problem(device, environ=None) -> str | None:
    """Why deterministic kernels cannot run on ``device`` (a
    ``torch.device``), or None: on CUDA, a cuBLAS workspace setting that
    PyTorch's deterministic mode refuses."""
    if getattr(device, 'type', device) != 'cuda':
        return None
    environ = os.environ if environ is None else environ
    value = environ.get(CUBLAS_VARIABLE)
    if value in CUBLAS_DETERMINISTIC:
        return None
    now = 'is unset' if value is None else f'is {value!r}'
    return (f'{CUBLAS_VARIABLE} {now}: deterministic CUDA kernels, which '
            'make the forces the same bits at the same positions, need '
            f'{CUBLAS_VARIABLE}={CUBLAS_DETERMINISTIC[0]} (or '
            f'{CUBLAS_DETERMINISTIC[1]}) set before CUDA starts. Set it in '
            f'the shell (export {CUBLAS_VARIABLE}={CUBLAS_DETERMINISTIC[0]})'
            ' or import ase_reversible.torch before the first CUDA call, '
            'which sets it if unset.')


def steady_torchscript() -> bool:
    """Turn TorchScript's profiling-guided optimisation off for the whole
    process (``torch.jit.optimized_execution(False)``, not restored), so a
    scripted model's results no longer depend on how often and at which
    shapes it ran before; returns whether it was on.

    Process-wide on purpose: a call anyone makes with it on (an observer,
    the user's own) changes what later calls return.  Called when a
    calculator that holds torch modules is taken on.
    """
    import torch
    flag = getattr(torch._C, '_get_graph_executor_optimize', None)
    if flag is None or not flag():
        return False
    torch._C._set_graph_executor_optimize(False)
    return True


@contextlib.contextmanager
def deterministic_kernels(warn_only: bool = False):
    """The context: ``torch.use_deterministic_algorithms(True,
    warn_only=warn_only)`` inside, the caller's setting (and its
    ``warn_only``) back after.

    ``warn_only=True`` lets an operation without a deterministic kernel
    run nondeterministically (PyTorch warns) instead of raising: for a
    third-party model, whose purity is then probed, not assumed.
    """
    import torch
    enabled = torch.are_deterministic_algorithms_enabled()
    was_warn_only = torch.is_deterministic_algorithms_warn_only_enabled()
    changed = not enabled or was_warn_only != warn_only
    if changed:
        torch.use_deterministic_algorithms(True, warn_only=warn_only)
    try:
        yield
    finally:
        if changed:
            torch.use_deterministic_algorithms(enabled,
                                               warn_only=was_warn_only)
