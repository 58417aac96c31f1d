"""One thread for OpenMP and BLAS around the force calls that need it.

A parallel sum adds its threads' partial sums in an order that can change
from call to call, so forces at the same state differ in the last bits:
tblite's GFN2-xTB on ethanol, started cold each call with two OpenMP
threads, gave forces up to 7.2e-16 eV/Å apart in 8 of 10 repeated calls
at identical positions; held to one thread (``threadpool_limits(1)``), 0
in 10 of 10.  No rounding rule absorbs that, so such calculators are run
with their thread pools held to one thread during each force call, by
``threadpoolctl``, and set back after it: the rest of the program keeps
its threads.
"""

from __future__ import annotations

#: Modules (their top-level package) of calculators known to sum forces
#: in OpenMP threads: these are held to one thread without a probe.
OPENMP_CALCULATOR_PACKAGES = ('tblite',)


def uses_openmp(calc) -> bool:
    """Whether ``calc`` is a calculator known to sum in OpenMP threads."""
    module = type(calc).__module__ or ''
    return module.split('.')[0] in OPENMP_CALCULATOR_PACKAGES


class OneThread:
    """A context that holds the OpenMP and BLAS thread pools loaded in this
    process to one thread, and sets them back on leaving.

    The libraries are found once, when this is made (after the calculator
    is imported, so that its own are among them); each entry then costs a
    read and a write of every pool's thread count.

    """

    def __init__(self):
        from threadpoolctl import ThreadpoolController
        self._controller = ThreadpoolController()

    def __call__(self):
        """The context: ``with one_thread(): atoms.get_forces()``."""
        return self._controller.limit(limits=1)

    @property
    def libraries(self):
        """``[(internal_api, filepath)]`` of the pools it holds."""
        return [(lib.internal_api, lib.filepath)
                for lib in self._controller.lib_controllers]


def one_thread():
    """A :class:`OneThread`; ImportError with the remedy if threadpoolctl,
    a dependency of this package, is missing."""
    try:
        return OneThread()
    except ImportError as error:
        raise ImportError(
            'threadpoolctl is needed to run this calculator exactly: its '
            'forces are summed in OpenMP threads, which must be held to one '
            'during force calls. Install it (pip install threadpoolctl).'
        ) from error
