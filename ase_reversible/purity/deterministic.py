"""Deterministic torch kernels around the force calls that need them.

A torch model on a GPU sums with atomic adds whose order changes from
call to call, so its forces at the same positions differ in the last
bits (the measurements are in :mod:`ase_reversible.core.kernels`).  For
a calculator that holds torch modules, ``force_purity='auto'`` holds
PyTorch's deterministic kernels around the calls whose forces must be the
same bits at the same positions: every call, or only a guarded provider's
clean recomputations (see :func:`~.choice.force_provider`).  The kernels
are :func:`~ase_reversible.core.kernels.deterministic_kernels` with
``warn_only=True``: a model with an operation that has no deterministic
kernel still runs, and the probe judges what it returns.
"""

from __future__ import annotations

import contextlib
import warnings

from ..core.kernels import deterministic_kernels

#: Words of PyTorch's warning for an operation without a deterministic
#: kernel under ``warn_only=True``.
_NONDETERMINISTIC_WARNING = 'does not have a deterministic implementation'


class DeterministicKernels:
    """A context: deterministic torch kernels inside (``warn_only=True``),
    the caller's setting restored after it.

    PyTorch warns at every call of an operation that lacks a deterministic
    kernel; a run would repeat that warning at every step, so each such
    warning is shown once per hold, and every other warning as it comes.

    Attributes
    ----------
    entries : int
        How many times the context was entered.
    """

    def __init__(self):
        self.entries = 0
        self._shown = set()

    @contextlib.contextmanager
    def __call__(self):
        """The context: ``with kernels(): atoms.get_forces()``."""
        self.entries += 1
        caught = []
        try:
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter('always')
                with deterministic_kernels(warn_only=True):
                    yield
        finally:
            self._show(caught)

    def _show(self, caught):
        """Issue the warnings caught in a call again, PyTorch's repeated
        ones about nondeterministic operations left out."""
        for warning in caught:
            text = str(warning.message)
            if _NONDETERMINISTIC_WARNING in text:
                if text in self._shown:
                    continue
                self._shown.add(text)
            warnings.warn_explicit(warning.message, warning.category,
                                   warning.filename, warning.lineno,
                                   source=warning.source)

