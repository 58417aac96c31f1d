"""Force purity: forces as an exact function of the positions.

Exact reversal needs every kick to be a function of the positions alone: the
reverse run meets each position again and must round the same increment.
Many calculators break this in the last bits: the order in which a
neighbour list visits pairs, and so the rounding of the sums, depends on
where that list was last built.  Forces at identical positions, after the
list had been built elsewhere first, differed by up to 2.3e-14 eV/Å for
ASE EMT on 500 periodic copper atoms and 7e-14 eV/Å for asap3 EMT; a
fixed-point Verlet run of that copper, 1000 steps out and back, then
missed its start by 16 position quanta (ASE) and 57 (asap3).  Three providers handle
this, chosen per calculator by :func:`force_provider`:

``'sorted'`` (ASE's LennardJones and EMT)
    The calculator's neighbour list is replaced by a sorted one.  Its
    sums then run over the same pairs in the same order whatever the
    history, so forces are bitwise reproducible at no cost per step.

``'guarded'`` (asap3 calculators)
    Forces may carry history noise up to a bound ``force_noise``.  A kick
    increment ``y`` (in quanta) is only rounded as computed when noise of
    that size could not move it across a rounding boundary; otherwise the
    forces are recomputed from a neighbour list built at exactly the
    current positions ("clean", a pure function of them) and rounded from
    those.  Both branches give ``rint(y_clean)``, so the kick is a pure
    function of the positions.  The momentum quantum is chosen coarse
    enough that clean recomputations are rare (about 1% of force calls).

``'trust'`` (pure calculators, and everything else after a probe)
    Forces are used as returned.  A calculator can declare itself pure with
    a class attribute ``forces_are_pure = True``; any other is first checked
    by :func:`probe_purity`, which recomputes forces at the same positions
    after moving the atoms elsewhere; a calculator that fails it raises
    :class:`ImpureForcesError` under ``'auto'``.

Where each part lives: :mod:`.providers` (the four handlings and the spot
check), :mod:`.probe`, :mod:`.choice` (``force_purity='auto'``),
:mod:`.check` (the probe and cost in the verdict of
:func:`ase_reversible.check_calculator`, which runs the integrators'
checks in :mod:`ase_reversible.md.verdict`), :mod:`.advice` (the messages),
:mod:`.introspection` (what a calculator is, mixes and holds),
:mod:`.threads` and :mod:`.deterministic` (the holds around force calls:
one thread, deterministic torch kernels) and
:mod:`.settings` (the bounds and their measurements, and the guard's
rules: :func:`guard_bound` and the momentum quantum it needs,
:func:`guarded_momentum_quantum`, which the LAMMPS drivers share).
"""

# The public names of every module, importable from the package.
# No __all__: the API pages document each object once, in its own module,
# and an __all__ here would document them a second time on this page.
from .check import CalculatorCheck, probed_check, refused_check
from .choice import force_provider
from .deterministic import DeterministicKernels
from .introspection import (calculator_members, cold_start, discard_results,
                            mixture, torch_devices, torch_modules)
from .probe import (measured_force_noise, noise_as_force_noise, probe_purity,
                    repeat_noise)
from .providers import (ColdStartForces, GuardedForces,
                        SortedNeighborListForces, SpotCheck, TrustedForces)
from .settings import (DEFAULT_FORCE_NOISE, MEASURED_NOISE_FLOOR,
                       MEASURED_NOISE_MARGIN, NOISE_REFERENCE_EXTENT,
                       REBUILD_SHIFT, RUN_TO_RUN_SHARE, SPOT_CHECK_INTERVAL,
                       SUMMATION_NOISE_LIMIT, TARGET_CLEAN_RATE,
                       extent_factor, guard_bound, guarded_momentum_quantum)
