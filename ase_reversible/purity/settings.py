"""The numbers force purity rests on: noise bounds, the probe's shift,
the spot check's interval, and how bounds scale."""

from __future__ import annotations

import math

#: Default bound on history noise in forces, eV/Å (scaled by max|F| above
#: 1 eV/Å).  The largest noise measured, asap3 EMT on periodic copper, was
#: 8.2e-14 eV/Å: this leaves a margin of 11.
DEFAULT_FORCE_NOISE = 2.0**-40
#: Fraction of force calls that may need a clean recomputation.
TARGET_CLEAN_RATE = 0.01
#: The bound ``'auto'`` sets is this many times the noise its probe saw.
MEASURED_NOISE_MARGIN = 16
#: ... and never below this (eV/Å, scaled as DEFAULT_FORCE_NOISE): the
#: probe can see no noise at all where a run meets some.  Measured in runs
#: of asap3 LennardJones on a 147-atom argon cluster (the forces of the
#: run against those of a list built at the same positions, 18,081
#: components): at most 4.2e-17 eV/Å; this floor is 21 times that.
MEASURED_NOISE_FLOOR = 2.0**-50
#: Coordinates (Å) up to which DEFAULT_FORCE_NOISE holds.  History noise
#: comes from rounding coordinate differences, so it grows with the
#: coordinates' magnitude (asap3 on periodic argon: 2e-15 eV/Å near the
#: origin, 5e-14 at 600 Å, 2e-13 at 3000 Å); beyond this extent the bound
#: grows in proportion.
NOISE_REFERENCE_EXTENT = 32.0
#: Distance (Å, per axis) the atoms are moved to force a neighbour-list
#: rebuild: more than any skin, so the list is rebuilt on the way back.
REBUILD_SHIFT = 8.0
#: Force calls from one spot check of purity to the next (see
#: :class:`SpotCheck`): one extra call in this many, and for asap3 two
#: neighbour-list rebuilds, stays below 1% of a run's force calls.
SPOT_CHECK_INTERVAL = 512

#: Largest history noise, relative to max(1 eV/Å, max|F|), that comes from
#: the order of floating-point sums (neighbour lists): such noise is a few
#: ulps, 1e-16 to 1e-13 relative.  A self-consistent field that starts from
#: its previous solution leaves noise near its convergence threshold
#: (tblite GFN2-xTB: 1.9e-4 eV/Å), far above this.
SUMMATION_NOISE_LIMIT = 1e-9

#: Forces that vary between calls repeated at the same positions by at
#: least this share of what the probe saw after moving the atoms vary from
#: call to call (parallel sums in a changing order), not with a history:
#: two samples of the same noise differ by far less than a factor of 8,
#: while a self-consistent field refined again from its own solution at
#: the same positions changes by a fraction of its history noise (the
#: contraction of its iterations, to the power of their number).
RUN_TO_RUN_SHARE = 1 / 8

#: Noise is *near* its bound, and a run warns, above the bound divided by
#: this.  The largest noise a run meets grows as it visits more positions,
#: but slowly: over five trials of the same system the largest noise per
#: trial varied by a factor of at most 1.5 (asap3 EMT, Cu500 periodic:
#: 5.2e-14 to 7.7e-14 eV/Å, docs/force-purity.md), so noise within a
#: factor of 2 of the bound may cross it later in the run, and noise
#: below half of it has that much room.
NEAR_BOUND_FACTOR = 2.0


def extent_factor(extent):
    """How the guard's bound grows with the coordinates' extent ``extent``
    (the largest ``|coordinate|``, Å or LAMMPS distance units): 1 up to
    ``NOISE_REFERENCE_EXTENT``, in proportion beyond (history noise comes
    from rounding coordinate differences)."""
    return max(1.0, extent / NOISE_REFERENCE_EXTENT)


def guard_bound(force_noise, extent, largest_force):
    """The history noise a force component may carry, in the unit of
    ``force_noise`` (eV/Å, or LAMMPS force units): ``force_noise`` scaled
    by :func:`extent_factor` of ``extent`` and by ``largest_force`` (the
    largest ``|F|`` component) above 1.  The one rule of the ASE
    integrators' guard, the LAMMPS drivers' and the calculator check."""
    return force_noise * extent_factor(extent) * max(1.0, largest_force)


def guarded_momentum_quantum(n_atoms, force_noise, kick_time, extent,
                             clean_rate=TARGET_CLEAN_RATE):
    """The finest momentum quantum for which about ``clean_rate`` of the
    force calls need a clean recomputation under the guard.

    ``n_atoms`` atoms, ``force_noise`` (force unit) as for
    :func:`guard_bound` at forces up to 1, ``kick_time`` the largest
    ``|c h|`` of a kick (time unit), ``extent`` as for
    :func:`extent_factor`.  Returns force x time (amu Å / ASE time unit
    in ASE's units); a caller in other units converts the result.
    """
    # P(clean) per force call ~ 2 * 3N * noise * |c h| / q_p.
    return (2 * 3 * max(n_atoms, 1) * force_noise * kick_time
            * extent_factor(extent) / clean_rate)


def _near_bound(noise, bound):
    """Whether ``noise`` has come within ``NEAR_BOUND_FACTOR`` of
    ``bound`` (or beyond it)."""
    return not noise <= bound / NEAR_BOUND_FACTOR


def _bound_for(noise):
    """The ``force_noise`` (eV/Å) to use where ``noise`` (already scaled
    back as ``force_noise`` is) was seen: ``MEASURED_NOISE_MARGIN`` times
    it, rounded up to two significant digits."""
    return _round_up(MEASURED_NOISE_MARGIN * noise)


def _round_up(value):
    """``value`` rounded up to two significant digits (0, NaN and
    infinities as they are)."""
    if not (math.isfinite(value) and value > 0):
        return value
    digits = math.floor(math.log10(value)) - 1
    return math.ceil(value / 10.0**digits) * 10.0**digits

