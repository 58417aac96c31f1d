"""The probe: forces at the same positions after another history."""

from __future__ import annotations

import math

import numpy as np

from .introspection import discard_all_results
from .settings import (DEFAULT_FORCE_NOISE, MEASURED_NOISE_FLOOR,
                       MEASURED_NOISE_MARGIN, REBUILD_SHIFT, guard_bound)


def measured_force_noise(atoms) -> float:
    """The guard's bound for these atoms' calculator, from a probe.

    ``MEASURED_NOISE_MARGIN`` times the noise :func:`probe_purity` sees
    (three trials), scaled back as ``force_noise`` is (to forces of 1 eV/Å
    and coordinates within ``NOISE_REFERENCE_EXTENT``), rounded up to a
    power of two, and kept between ``MEASURED_NOISE_FLOOR`` and
    ``DEFAULT_FORCE_NOISE``.  asap3 on a free argon cluster shows noise a
    ten-thousandth of the default bound; periodic copper under EMT shows
    it near the default, which then stays.  The bound is checked during
    the run: every clean recomputation and spot check compares it with
    the noise it sees and stops the run if it was exceeded.
    """
    return min(noise_as_force_noise(atoms, probe_purity(atoms, trials=3)),
               DEFAULT_FORCE_NOISE)


def noise_as_force_noise(atoms, noise, forces=None) -> float:
    """The ``force_noise`` (eV/Å) for ``noise`` (eV/Å) seen at the atoms'
    positions: ``MEASURED_NOISE_MARGIN`` times it, scaled back as
    ``force_noise`` is (to forces of 1 eV/Å and coordinates within
    ``NOISE_REFERENCE_EXTENT``), rounded up to a power of two, at least
    ``MEASURED_NOISE_FLOOR``; no upper bound (:func:`measured_force_noise`
    keeps it within ``DEFAULT_FORCE_NOISE``).  ``forces(atoms)``, if
    given, is how the forces are obtained."""
    x_nc = atoms.positions
    extent = max(x_nc.max(initial=0.0), -x_nc.min(initial=0.0))
    f_nc = (atoms.get_forces(md=True) if forces is None
            else np.asarray(forces(atoms)))
    f_max = max(f_nc.max(initial=0.0), -f_nc.min(initial=0.0))
    scaled = noise / guard_bound(1.0, extent, f_max)
    wanted = max(MEASURED_NOISE_MARGIN * scaled, MEASURED_NOISE_FLOOR)
    return 2.0**math.ceil(math.log2(wanted))


def repeat_noise(atoms, forces=None, repeats: int = 2) -> float:
    """Largest force difference (eV/Å) between calls at the same
    positions with nothing between them: the calculator's cached results
    are discarded and it is called again, ``repeats`` times after the
    first.  The calculator saw no other positions between them, so noise
    here, nearly as large as the probe's, is run-to-run nondeterminism
    (parallel sums whose order changes from call to call); a history
    carried on from one repeat to the next (a self-consistent field
    refined again) changes far less (``RUN_TO_RUN_SHARE``).  Costs
    ``1 + repeats`` force calls; ``forces(atoms)`` as for
    :func:`probe_purity`."""
    if forces is None:
        def forces(atoms):
            return atoms.get_forces(md=True)
    discard_all_results(atoms.calc)
    f0_nc = np.array(forces(atoms))
    worst = 0.0
    for _ in range(repeats):
        discard_all_results(atoms.calc)
        worst = max(worst, float(np.abs(np.asarray(forces(atoms))
                                        - f0_nc).max(initial=0.0)))
    return worst


def probe_purity(atoms, trials: int = 2, displacement: float = 0.3,
                 seed: int = 0, forces=None) -> float:
    """Largest force difference (eV/Å) at identical positions.

    ``atoms`` needs a calculator.  Costs ``1 + 3 * trials`` force calls.
    Computes the forces, then, ``trials`` times: moves the atoms away (a
    random displacement of ``displacement`` Å rms plus a shift of
    ``REBUILD_SHIFT`` Å, so that neighbour lists are rebuilt), then close to
    the start (0.05 Å rms: lists are rebuilt there, not at the start), then
    back bit for bit, and computes again.  Zero means no history dependence
    was seen, which is evidence, not proof, of purity.  The atoms are left
    at their original positions.  ``forces(atoms)``, if given, is how the
    forces are obtained (a provider's ``forces``, to probe its handling).
    """
    if forces is None:
        def forces(atoms):
            return atoms.get_forces(md=True)
    rng = np.random.default_rng(seed)
    x_nc = atoms.positions.copy()
    discard_all_results(atoms.calc)
    f0_nc = np.array(forces(atoms))
    worst = 0.0
    try:
        for _ in range(trials):
            atoms.positions = (x_nc + REBUILD_SHIFT
                               + rng.normal(0.0, displacement, x_nc.shape))
            forces(atoms)
            atoms.positions = x_nc + rng.normal(0.0, 0.05, x_nc.shape)
            forces(atoms)
            atoms.positions = x_nc
            worst = max(worst, float(np.abs(forces(atoms) - f0_nc).max()))
    finally:
        atoms.positions = x_nc
    return worst
