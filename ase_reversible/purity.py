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
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

import numpy as np

from .core.codec import guard_band_crossed, round_odd
from .errors import ImpureForcesError

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


class SpotCheck:
    """Now and then, forces recomputed where the run has been, compared.

    The probe at construction moves the atoms away and back a few times;
    a calculator whose sums change from call to call (threads, GPUs,
    reductions in a varying order) can pass it by luck.  So once every
    ``interval`` force calls the positions and forces are kept, and half an
    interval later, when the calculator has moved on, the forces at the
    kept positions are computed again and handed to the provider's
    :meth:`~TrustedForces.compare_visit`, which raises if they betray a
    history.  Costs one force call per ``interval``.

    Attributes
    ----------
    checks : int
        Comparisons made so far.
    """

    def __init__(self, interval: int = SPOT_CHECK_INTERVAL):
        self.interval = interval
        self.checks = 0
        self._countdown = interval
        self._kept = None  # (positions [n_atoms, 3], forces [n_atoms, 3])

    def due(self) -> bool:
        """Counts a force call; whether it is one that keeps or checks."""
        self._countdown -= 1
        return self._countdown <= 0

    def visit(self, provider, atoms):
        """The forces at the present positions, keeping or checking."""
        half = self.interval // 2
        if self._kept is None:
            f_nc = provider.evaluate(atoms)
            self._kept = (atoms.positions.copy(), np.array(f_nc))
            self._countdown = half
            return f_nc
        x_kept, f_kept = self._kept
        self._kept = None
        self._countdown = self.interval - half
        x_now = atoms.positions.copy()
        atoms.positions = x_kept
        try:
            f_again = provider.evaluate(atoms)
        finally:
            atoms.positions = x_now
        self.checks += 1
        provider.compare_visit(atoms, f_kept, np.array(f_again), half)
        return provider.evaluate(atoms)


class TrustedForces:
    """Forces used as the calculator returns them.

    ``spot_check`` (a :class:`SpotCheck`, or None) checks during runs that
    the forces stay a function of the positions.
    """

    mode = 'trust'
    force_noise = 0.0
    spot_check = None

    def forces(self, atoms) -> np.ndarray:
        """Forces ``[n_atoms, 3]`` (eV/Å) at the atoms' current positions.

        ``md=True``: constraints are not applied (the integrator projects).
        """
        spot = self.spot_check
        if spot is not None and spot.due():
            return spot.visit(self, atoms)
        return self.evaluate(atoms)

    def evaluate(self, atoms) -> np.ndarray:
        """The forces, without the spot check (see :meth:`forces`)."""
        return atoms.get_forces(md=True)

    def compare_visit(self, atoms, f_kept, f_again, calls):
        """Raise :class:`ImpureForcesError` unless ``f_again``, computed now
        at positions visited ``calls`` force calls ago, is ``f_kept``
        bit for bit."""
        if np.array_equal(f_kept, f_again):
            return
        noise = float(np.nanmax(np.abs(f_again - f_kept)))
        raise ImpureForcesError(_spot_check_advice(
            atoms.calc, self.mode, noise, calls))

    def rounded_kick(self, atoms, f_nc, scale, project, out, scratch):
        """The kick in quanta, ``rint(project(scale * f_nc))``, into ``out``.

        ``f_nc``: forces ``[n_atoms, 3]``, eV/Å; ``scale``: ``c h / q_p``
        (quanta per eV/Å); ``project``: the in-place constraint projection.
        ``out`` and ``scratch`` are float arrays ``[n_atoms, 3]``; the
        caller adds ``out`` to the momentum counts.  Returns the forces the
        kick was computed from (``f_nc`` or a clean recomputation).
        """
        np.multiply(f_nc, scale, out=out)
        project(out)
        round_odd(out, out=out)
        return f_nc

    def min_momentum_quantum(self, n_atoms, max_kick_time, extent=0.0):
        """Lower bound on the momentum quantum this provider needs.

        ``max_kick_time``: the largest ``|c h|`` of a kick, ASE time units;
        ``extent``: the largest ``|coordinate|``, Å.  Returns amu Å / ASE time
        unit; 0 means no bound.
        """
        return 0.0

    def todict(self):
        """``{'mode': ...}`` and the provider's settings."""
        return {'mode': self.mode}


class SortedNeighborListForces(TrustedForces):
    """ASE calculators with an ``ase.neighborlist.NeighborList`` in ``.nl``.

    Also a mixing calculator (SumCalculator, ...) whose members include
    such calculators: each of those gets a sorted list.  A calculator
    creates its list on the first calculation (and again when the atomic
    numbers change); the list is then swapped for a sorted copy and the
    unsorted results are discarded, costing one extra force call.

    Parameters
    ----------
    listed : sequence of calculators, optional
        The calculators (the attached one or its members) that keep a
        neighbour list in ``.nl``; default: the attached one.
    """

    mode = 'sorted'

    def __init__(self, listed=None):
        self._listed = None if listed is None else tuple(listed)

    def evaluate(self, atoms):
        f_nc = atoms.get_forces(md=True)
        listed = (atoms.calc,) if self._listed is None else self._listed
        # Checked after the call: the calculator may have (re)built an
        # unsorted list inside it, or answered from a cache filled by one.
        if all(map(_has_sorted_list, listed)):
            return f_nc
        for calc in listed:
            if not _has_sorted_list(calc):
                _install_sorted_list(calc)
        # Mixing calculators, nested ones too, cache their members' sums.
        for calc in calculator_members(atoms.calc):
            discard_results(calc)
        return atoms.get_forces(md=True)


class GuardedForces(TrustedForces):
    """Noisy forces made exact by guarded rounding (see module docstring).

    Parameters
    ----------
    force_noise : float
        Bound on the history noise of a force component, eV/Å, for forces
        up to 1 eV/Å and coordinates up to ``NOISE_REFERENCE_EXTENT``;
        scaled by max|F| and by max|x| / ``NOISE_REFERENCE_EXTENT`` above.
    """

    mode = 'guarded'

    def __init__(self, force_noise: float = DEFAULT_FORCE_NOISE):
        force_noise = float(force_noise)
        if not (math.isfinite(force_noise) and force_noise > 0):
            raise ValueError(f'force_noise must be positive and finite (eV/Å),'
                             f' got {force_noise!r}')
        self.force_noise = force_noise
        #: Number of kicks whose forces were recomputed from a clean list.
        self.clean_recomputations = 0
        #: Largest ``|F_history - F_clean|`` seen in those recomputations,
        #: eV/Å.
        self.max_observed_noise = 0.0
        self._warned = False
        self._clean_nc = None  # the last clean forces: need no guard

    def rounded_kick(self, atoms, f_nc, scale, project, out, scratch):
        y_nc = scratch
        np.multiply(f_nc, scale, out=y_nc)
        project(y_nc)
        round_odd(y_nc, out=out)
        if f_nc is self._clean_nc:
            return f_nc
        noise = self.noise_bound(atoms, f_nc)
        # NaN forces are not flagged and go straight back to the caller,
        # which refuses them.
        if not guard_band_crossed(y_nc, out, abs(scale) * noise):
            return f_nc
        clean_nc = self.clean_forces(atoms)
        self._record_noise(atoms, np.abs(clean_nc - f_nc).max(), noise)
        np.multiply(clean_nc, scale, out=out)
        project(out)
        round_odd(out, out=out)
        return clean_nc

    def noise_bound(self, atoms, f_nc):
        """The history noise (eV/Å) the guard allows at these positions
        and forces ``[n_atoms, 3]``: ``force_noise`` scaled by the
        coordinates' extent and by max|F| above 1 eV/Å."""
        x_nc = atoms.positions
        extent = max(x_nc.max(initial=0.0), -x_nc.min(initial=0.0))
        f_max = max(f_nc.max(initial=0.0), -f_nc.min(initial=0.0))
        return self.force_noise * _extent_factor(extent) * max(1.0, f_max)

    def compare_visit(self, atoms, f_kept, f_again, calls):
        """Raise :class:`ImpureForcesError` if the forces at positions
        visited ``calls`` force calls ago differ now by more than the noise
        bound the guard relies on."""
        noise = float(np.nanmax(np.abs(f_again - f_kept)))
        bound = self.noise_bound(atoms, f_kept)
        self._record_noise(atoms, noise, bound, calls)

    def clean_forces(self, atoms):
        """Forces ``[n_atoms, 3]`` (eV/Å) from a neighbour list built at
        exactly these positions: the atoms are moved ``REBUILD_SHIFT`` Å away
        and back, bit for bit."""
        x_nc = atoms.positions.copy()
        atoms.positions = x_nc + REBUILD_SHIFT
        try:
            # Every atom now sits further than any skin from where the list
            # was built, so it is rebuilt here and again, at exactly x_nc,
            # on the way back.  asap3 can update its list without computing
            # forces, which saves a third of the cost.
            update = getattr(atoms.calc, 'check_update_neighborlist', None)
            if update is not None:
                update(atoms)
            else:
                atoms.get_forces(md=True)
        finally:
            atoms.positions = x_nc
        self.clean_recomputations += 1
        self._clean_nc = atoms.get_forces(md=True)
        return self._clean_nc

    def _record_noise(self, atoms, noise, bound, calls=None):
        """Keep the largest noise seen; raise if it broke the bound (an
        earlier kick may then have been rounded from noisy forces), warn
        once when it comes within a factor of 8.  ``calls``: how many
        force calls apart the two forces were (a spot check), or None (a
        clean recomputation)."""
        noise = float(noise)
        self.max_observed_noise = max(self.max_observed_noise, noise)
        if not noise <= bound:
            raise ImpureForcesError(_spot_check_advice(
                atoms.calc, self.mode, noise, calls, bound))
        if noise > bound / 8 and not self._warned:
            self._warned = True
            warnings.warn(
                f'Force noise of {noise:.3g} eV/Å was observed, close to the '
                f'bound of {bound:.3g} eV/Å (force_noise='
                f'{self.force_noise:.3g} eV/Å, scaled by the coordinates\' '
                'extent and max|F|) that exact reversal relies on. Construct the '
                'integrator with a larger force_noise.', RuntimeWarning,
                stacklevel=4)

    def min_momentum_quantum(self, n_atoms, max_kick_time, extent=0.0):
        # P(clean) per force call ~ 2 * 3N * noise * |c h| / q_p.
        return (2 * 3 * max(n_atoms, 1) * self.force_noise * max_kick_time
                * _extent_factor(extent) / TARGET_CLEAN_RATE)

    def todict(self):
        """``{'mode': 'guarded', 'force_noise': ...}`` (eV/Å)."""
        return {'mode': self.mode, 'force_noise': self.force_noise}


class ColdStartForces(TrustedForces):
    """Every force call starts from the calculator's initial state.

    For self-consistent-field calculators (tight binding, DFT) that start
    each SCF from the previous solution: their forces then differ, at
    identical positions, by about the convergence threshold, depending on
    where they were before.  Dropping the previous solution before each
    call makes the forces a pure function of the positions again, at the
    cost of the extra SCF iterations a cold start needs.  How the state is
    dropped is :func:`cold_start`.
    """

    mode = 'cold-start'

    def evaluate(self, atoms):
        cold_start(atoms.calc)
        return atoms.get_forces(md=True)


def cold_start(calc):
    """Make the next calculation of ``calc`` (and of every calculator it
    mixes) start from scratch at the present positions.

    tblite's ASE calculator keeps its last SCF solution as the next guess,
    and its ``reset()`` keeps it too (unless ``cache_api=False``, which
    also rebuilds the whole setup on every call): the guess is dropped
    directly, the setup kept.  Any other calculator gets ASE's
    ``reset()``, the documented way to forget a calculation's state.
    """
    for c in calculator_members(calc):
        if type(c).__module__.startswith('tblite.'):
            discard_results(c)
            c._res = None  # the previous SCF solution
        elif callable(getattr(c, 'reset', None)):
            c.reset()
        else:
            discard_results(c)


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
    noise = probe_purity(atoms, trials=3)
    x_nc = atoms.positions
    extent = max(x_nc.max(initial=0.0), -x_nc.min(initial=0.0))
    f_nc = atoms.get_forces(md=True)
    f_max = max(f_nc.max(initial=0.0), -f_nc.min(initial=0.0))
    scaled = noise / (_extent_factor(extent) * max(1.0, f_max))
    wanted = max(MEASURED_NOISE_MARGIN * scaled, MEASURED_NOISE_FLOOR)
    return min(2.0**math.ceil(math.log2(wanted)), DEFAULT_FORCE_NOISE)


def _extent_factor(extent):
    return max(1.0, extent / NOISE_REFERENCE_EXTENT)


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
    discard_results(atoms.calc)
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


def force_provider(atoms, mode: str = 'auto',
                   force_noise: float | None = None):
    """Choose how forces are made a pure function of positions.

    Parameters
    ----------
    atoms : ase.Atoms
        With its calculator attached.
    mode : {'auto', 'sorted', 'guarded', 'cold-start', 'trust'}
        ``'auto'`` looks at the calculator and, for a mixing calculator
        (anything with members in ``.calcs``: SumCalculator,
        LinearCombinationCalculator, MixedCalculator), at every member,
        and takes the strictest handling any of them needs: ``'guarded'``
        if one is an asap3 calculator; else ASE's LennardJones and EMT get
        sorted neighbour lists (``'sorted'``); members that are neither
        these nor declare ``forces_are_pure = True`` (a guarantee that
        forces are a function of the positions alone) make it probe the
        whole calculator with :func:`probe_purity`.  If its forces depend
        on its history by more than summation order explains, it probes
        again with every call started cold (:class:`ColdStartForces`) and
        takes ``'cold-start'`` if that makes them pure; otherwise it
        refuses the calculator.
    force_noise : float, optional
        Noise bound for ``'guarded'`` (eV/Å).

    Returns
    -------
    TrustedForces, SortedNeighborListForces, GuardedForces or ColdStartForces
        Raises :class:`ImpureForcesError` if ``'auto'`` probes the
        calculator and sees history noise.
    """
    provider = _provider(atoms, mode, force_noise)
    # Pure by construction (sorted lists in ASE's own calculators, or a
    # declaration) needs no watching; a probe's verdict, a noise bound or
    # a user's word gets a spot check during runs.
    if not _pure_by_construction(atoms.calc):
        provider.spot_check = SpotCheck()
    return provider


def _pure_by_construction(calc):
    if _declares_pure(calc):
        return True
    members = calculator_members(calc)
    leaves = [c for c in members if not _mixes(c)] or [calc]
    return all(_declares_pure(c) or _is_plain_ase_neighborlist_calculator(c)
               for c in leaves)


def _provider(atoms, mode, force_noise):
    calc = atoms.calc
    modes = ('auto', 'sorted', 'guarded', 'cold-start', 'trust')
    if mode not in modes:
        raise ValueError(f'force_purity must be one of {modes}, got {mode!r}')
    if force_noise is not None and mode not in ('auto', 'guarded'):
        raise ValueError("force_noise only applies to force_purity='guarded'")
    members = calculator_members(calc)
    listed = [c for c in members if _is_ase_neighborlist_calculator(c)]
    if mode == 'auto':
        # A mixing calculator is as impure as its worst member: its own
        # probe can pass while a member's history has not shown yet.
        leaves = [c for c in members if not _mixes(c)] or [calc]
        if _declares_pure(calc):
            mode = 'trust'
        elif force_noise is not None:
            mode = 'guarded'
        elif _is_asap3(calc):
            return GuardedForces(measured_force_noise(atoms))
        elif any(_is_asap3(c) for c in leaves):
            # Mixed with others (by a user's wrapper: ASE's mixers do not
            # take asap3) the probe would move atoms under calculators it
            # knows nothing of: the fixed bound.
            mode = 'guarded'
        elif all(_declares_pure(c) or _is_plain_ase_neighborlist_calculator(c)
                 for c in leaves):
            mode = 'sorted' if listed else 'trust'
        else:
            provider = (SortedNeighborListForces(listed) if listed
                        else TrustedForces())
            if listed:  # sorted lists in place before the probe
                provider.forces(atoms)
            noise = probe_purity(atoms)
            if not noise:
                return provider
            f_max = np.abs(provider.forces(atoms)).max(initial=0.0)
            if not listed and noise > SUMMATION_NOISE_LIMIT * max(1.0, f_max):
                # Noise this large is state carried between calls (an SCF
                # started from its last solution): try starting cold.
                cold = ColdStartForces()
                left = probe_purity(atoms, forces=cold.forces)
                if not left:
                    return cold
                if left <= SUMMATION_NOISE_LIMIT * max(1.0, f_max):
                    raise ImpureForcesError(_parallel_noise_advice(
                        calc, noise, left))
            raise ImpureForcesError(_impurity_advice(
                calc, noise, f_max, cold_start_tried=not listed))
    if mode == 'sorted':
        if not listed:
            raise ValueError(
                "force_purity='sorted' needs an ASE calculator that keeps "
                "an ase.neighborlist.NeighborList in .nl (LennardJones, "
                "EMT), or a mixing calculator with such members; "
                f"{type(calc).__name__} is neither.")
        return SortedNeighborListForces(listed)
    if mode == 'guarded':
        return GuardedForces(DEFAULT_FORCE_NOISE if force_noise is None
                             else force_noise)
    if mode == 'cold-start':
        return ColdStartForces()
    return TrustedForces()


#: Largest history noise, relative to max(1 eV/Å, max|F|), that comes from
#: the order of floating-point sums (neighbour lists): such noise is a few
#: ulps, 1e-16 to 1e-13 relative.  A self-consistent field that starts from
#: its previous solution leaves noise near its convergence threshold
#: (tblite GFN2-xTB: 1.9e-4 eV/Å), far above this.
SUMMATION_NOISE_LIMIT = 1e-9


def _impurity_advice(calc, noise, f_max, cold_start_tried=False):
    """The ImpureForcesError message, with the remedy for the likely cause."""
    name = type(calc).__name__
    head = (f'{name} returned forces that differ by {noise:.3g} eV/Å at '
            'identical positions after the atoms had been moved elsewhere: '
            'its forces depend on its history, which breaks exact '
            'reversal.')
    if noise <= SUMMATION_NOISE_LIMIT * max(1.0, f_max):
        # Sixteen times what was seen keeps it below the bound / 8 at
        # which guarded rounding warns that the bound is being approached.
        bound = max(DEFAULT_FORCE_NOISE, _round_up(16 * noise))
        return (f'{head} Noise this small comes from the order of '
                'floating-point sums (a neighbour list built elsewhere): '
                "construct the integrator with force_purity='guarded', "
                f'force_noise={bound:.2g} (eV/Å, at least sixteen times what '
                "was seen). force_purity='trust' skips this check.")
    return (f'{head} Noise this large does not come from summation order '
            'but from state the calculator carries between calls, such as '
            'a self-consistent field (DFT, tight binding) that starts from '
            'the previous solution. '
            + ("Calling the calculator's reset() before every call "
               "(force_purity='cold-start') did not remove it. "
               if cold_start_tried else '')
            + 'Make every calculation start from '
            'scratch (reset the initial guess or wavefunction before each '
            'call, for example in a subclass whose calculate() does that '
            'first), then construct the integrator again. Guarded rounding '
            'cannot absorb noise this large: the momentum quantum would '
            'have to be so coarse that the momenta lose their precision.')


def _spot_check_advice(calc, mode, noise, calls, bound=None):
    """The message for forces found depending on history during a run: by
    a spot check ``calls`` force calls apart, or (``calls`` None) by a
    clean recomputation; ``bound``: the guard's, if one was broken."""
    head = (f'{type(calc).__name__} gave forces {noise:.3g} eV/Å different '
            + (f'from those it gave at the same positions {calls} force '
               'calls earlier in this run' if calls is not None else
               'from those of a neighbour list built at exactly these '
               'positions'))
    tail = (' The run so far may not reverse exactly past the point where '
            'this started; the step was not taken.')
    if bound is not None:
        return (f"{head}, more than the {bound:.3g} eV/Å that "
                f"force_purity='{mode}' relies on.{tail} Construct the "
                'integrator with force_noise='
                f'{_round_up(16 * noise):.2g} (eV/Å, sixteen times what was '
                'seen) and run again.')
    return (f"{head}: under force_purity='{mode}' they must be equal bit "
            'for bit, so the forces are not a function of the positions '
            'alone, although the probe at construction saw no '
            f'difference.{tail} The usual cause is parallel sums whose '
            'order changes from call to call (threads, a GPU): run with one '
            'thread (OMP_NUM_THREADS=1 before Python starts), or, if the '
            "difference is at the level of rounding, use force_purity="
            f"'guarded' with force_noise={_round_up(16 * noise):.2g}.")


def _parallel_noise_advice(calc, noise, left):
    """The message for forces that a cold start makes nearly, not fully,
    pure: what is left varies from call to call at the same state."""
    return (f'{type(calc).__name__} returned forces that differ by '
            f'{noise:.3g} eV/Å at identical positions after the atoms had '
            'been moved elsewhere (a self-consistent field started from its '
            "last solution). Starting every call cold (force_purity="
            f"'cold-start') leaves {left:.3g} eV/Å: a difference at the "
            'level of rounding that varies from call to call even at the '
            'same state, as parallel sums do whose order depends on the '
            'threads (OpenMP). Run with one thread (set OMP_NUM_THREADS=1 '
            'before Python starts) and construct the integrator again.')


def _round_up(value):
    """``value`` rounded up to two significant digits."""
    digits = math.floor(math.log10(value)) - 1
    return math.ceil(value / 10.0**digits) * 10.0**digits


def _is_ase_neighborlist_calculator(calc):
    from ase.calculators.emt import EMT
    from ase.calculators.lj import LennardJones
    return isinstance(calc, (EMT, LennardJones))


def _mixes(calc):
    return mixture(calc) is not None


def _declares_pure(calc):
    return getattr(calc, 'forces_are_pure', False) is True


def _is_plain_ase_neighborlist_calculator(calc):
    # A subclass may add history of its own (a cache, a warm start): its
    # lists are sorted all the same, but it is probed.
    from ase.calculators.emt import EMT
    from ase.calculators.lj import LennardJones
    return type(calc) in (EMT, LennardJones)


def _is_asap3(calc):
    module = type(calc).__module__ or ''
    return module.split('.')[0] in ('asap3', '_asap')


def _has_sorted_list(calc):
    nl = getattr(calc, 'nl', None)
    return nl is not None and getattr(nl.nl, 'sorted', False)


def _install_sorted_list(calc):
    from ase.neighborlist import NeighborList
    old = calc.nl.nl
    new = NeighborList(old.cutoffs - old.skin, skin=old.skin, sorted=True,
                       self_interaction=old.self_interaction,
                       bothways=old.bothways)
    new.nl.cutoffs = old.cutoffs.copy()
    calc.nl = new
    discard_results(calc)


def discard_results(calc):
    """Forget a calculator's cached results (if it keeps ASE's dict), so
    that the next call computes them again."""
    results = getattr(calc, 'results', None)
    if isinstance(results, dict):
        results.clear()
        # Some calculators (LAMMPSlib) compute nothing when check_state()
        # sees the atoms unchanged: forget the atoms too.  Not ASE's
        # LennardJones and EMT, which would then rebuild the sorted list
        # as for new atomic numbers; they compute whatever is missing.
        # Nor asap3's, whose C++ side keeps a pointer to the atoms it was
        # given and fails an assertion when they vanish.
        if (getattr(calc, 'atoms', None) is not None
                and not _is_ase_neighborlist_calculator(calc)
                and not _is_asap3(calc)):
            calc.atoms = None


def calculator_members(calc):
    """``calc`` and, recursively, every calculator it mixes (``.calcs``).

    See :func:`mixture`.  Returns a list, ``calc`` first (empty for
    None).
    """
    if calc is None:
        return []
    out, stack, seen = [], [calc], set()
    while stack:
        c = stack.pop()
        if id(c) in seen:
            continue
        seen.add(id(c))
        out.append(c)
        mixed = mixture(c)
        if mixed is not None:
            stack.extend(reversed(mixed[0]))
    return out


def mixture(calc):
    """``(members, weights)`` of a calculator that mixes others, or None.

    ASE's SumCalculator, LinearCombinationCalculator, MixedCalculator and
    AverageCalculator keep their members and weights in ``.mixer`` (ASE
    3.29) or on themselves (``.calcs``, ``.weights``, earlier versions);
    a user's wrapper with ``.calcs`` counts too.  ``weights`` may be None.
    """
    for holder in (calc, getattr(calc, 'mixer', None)):
        members = getattr(holder, 'calcs', None)
        if isinstance(members, (list, tuple)):
            return list(members), getattr(holder, 'weights', None)
    return None


@dataclass(frozen=True)
class CalculatorCheck:
    """What :func:`check_calculator` found; ``str()`` gives a summary.

    Attributes
    ----------
    calculator : str
        The calculator's class name.
    exact : bool
        Whether a run with it reverses bit for bit under ``mode``.
    mode : str or None
        The force-purity mode ``force_purity='auto'`` chooses (``'trust'``,
        ``'sorted'``, ``'guarded'``), None if it refuses the calculator.
    probe_noise : float
        Largest force difference at identical positions that the probe
        saw after the mode's handling (eV/Å); 0.0 for a declared-pure
        calculator, which is not probed; NaN for a refused one (its
        message has the numbers).
    cost : str
        What the mode costs, in force calls and in momentum precision.
    advice : str or None
        For a refused calculator, the error's message: what to do.
    """

    calculator: str
    exact: bool
    mode: str | None
    probe_noise: float
    cost: str
    advice: str | None = None

    def __str__(self):
        if self.mode is None:
            return f'{self.calculator}: refused. {self.advice}'
        verdict = (f"exact, force_purity='{self.mode}'" if self.exact
                   else f"not exact under force_purity='{self.mode}'")
        text = (f'{self.calculator}: {verdict}; probe noise '
                f'{self.probe_noise:.3g} eV/Å. Cost: {self.cost}')
        return text + (f' {self.advice}' if self.advice else '')


_COSTS = {
    'trust': 'none: forces are used as the calculator returns them.',
    'sorted': 'one extra force call when the sorted neighbour list is '
              'installed, nothing per step.',
    'cold-start': 'every force call starts its self-consistent field from '
                  'scratch instead of from the previous solution (more '
                  'iterations per call).',
    'guarded': 'a clean recomputation (a neighbour-list rebuild and a '
               'force call) for about {rate:.0%} of the kicks, and a '
               'momentum quantum raised so that they stay that rare.',
}


def check_calculator(atoms, timestep=None, force_noise=None):
    """Tell whether the atoms' calculator gives exactly reversible forces.

    Chooses the force-purity mode as ``ReversibleVerlet(...,
    force_purity='auto')`` would, then probes the forces under that
    handling with :func:`probe_purity`: 7 force calls, and 7 more for
    each probe the choice itself made (an unknown calculator is probed,
    and probed again from a cold start if its history noise is large).  Nothing
    about the atoms is changed; an ASE LennardJones or EMT gets its
    sorted neighbour list, as it would from the integrator.

    Parameters
    ----------
    atoms : ase.Atoms
        With the calculator attached and the positions a run starts from.
    timestep : float, optional
        ASE time units.  With it, the cost of ``'guarded'`` includes the
        bits of momentum precision its coarser quantum gives up.
    force_noise : float, optional
        eV/Å, as for the integrator (implies ``'guarded'``).

    Returns
    -------
    CalculatorCheck
    """
    calc = atoms.calc
    if calc is None:
        raise RuntimeError('The atoms have no calculator: attach one '
                           '(atoms.calc = ...) to check it.')
    name = type(calc).__name__
    try:
        provider = force_provider(atoms, 'auto', force_noise)
    except ImpureForcesError as error:
        return CalculatorCheck(name, False, None, math.nan,
                               'not runnable as it is.', str(error))
    provider.forces(atoms)  # sorted lists in place before the probe
    noise = (0.0 if _declares_pure(calc)
             else probe_purity(atoms, forces=provider.forces))
    cost = _COSTS[provider.mode].format(rate=TARGET_CLEAN_RATE)
    exact, advice = noise == 0.0, None
    if provider.mode == 'guarded':
        f_max = float(np.abs(provider.forces(atoms)).max(initial=0.0))
        extent = float(np.abs(atoms.positions).max(initial=0.0))
        bound = provider.force_noise * max(1.0, f_max) * _extent_factor(extent)
        # Noise below the guard's bound cannot change a rounded kick.
        exact = noise < bound / 8
        if not exact:
            advice = (f'The noise is close to or above the bound of '
                      f'{bound:.3g} eV/Å: pass force_noise='
                      f'{_round_up(16 * noise):.2g} or larger.')
        if timestep is not None:
            from .core.quanta import choose_momentum_quantum
            fine = choose_momentum_quantum(
                atoms.get_masses(),
                atoms.arrays.get('momenta', np.zeros((len(atoms), 3))))
            floor = provider.min_momentum_quantum(
                len(atoms), 0.5 * abs(float(timestep)), extent=extent)
            quantum = (fine if floor <= fine
                       else math.ldexp(1.0, math.frexp(floor)[1]))
            cost += (f' With this time step: a momentum quantum of '
                     f'{quantum:.3g} instead of {fine:.3g} '
                     f'({math.log2(quantum / fine):.0f} bits of precision '
                     'fewer).')
    return CalculatorCheck(name, exact, provider.mode, noise, cost, advice)
