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

TorchScript adds a history of its own: its graph executor profiles the
first call of a scripted function at each input shape and then runs an
optimised graph, with other last bits.  MACE's ASE calculator (e3nn's
scripted tensor products, CPU, float64) gave one result at the first call
and another at every later one at the same positions, and a float32 run
under 'auto' came back with other momenta once in seven tries (the shapes
change as pairs enter and leave the cut-off, so the first visit of a shape
differed from the second).  Without the profiling-guided optimisation
(``torch.jit.optimized_execution(False)``) the same calls gave the same
bits from the first, and took 48 against 88 ms (float64) and 37 against
69 ms (float32) per call for 32 copper atoms on the CPU.

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
    :data:`CUBLAS_DETERMINISTIC`.  Called when ``ase_reversible.torch`` is
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


@contextlib.contextmanager
def unoptimised_jit():
    """The context: TorchScript's graph executor without profiling-guided
    optimisation inside (``torch.jit.optimized_execution(False)``), so a
    scripted function gives the same bits at its first call at a shape as
    at its later ones; the caller's setting back after."""
    import torch
    with torch.jit.optimized_execution(False):
        yield


@contextlib.contextmanager
def deterministic_kernels(warn_only: bool = False):
    """The context: ``torch.use_deterministic_algorithms(True,
    warn_only=warn_only)`` and :func:`unoptimised_jit` inside, the
    caller's settings (and its ``warn_only``) back after.

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
        with unoptimised_jit():
            yield
    finally:
        if changed:
            torch.use_deterministic_algorithms(enabled,
                                               warn_only=was_warn_only)
