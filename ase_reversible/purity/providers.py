"""Force providers: how each mode turns forces into a pure kick."""

from __future__ import annotations

import numpy as np
from ase.constraints import FixLinearTriatomic

from ..core.arguments import checked_positive
from ..core.codec import guard_band_crossed, round_odd
from ..errors import ImpureForcesError
from .advice import _spot_check_advice, warn_at_user_line
from .introspection import (_has_sorted_list, _install_sorted_list,
                            calculator_members, cold_start, discard_results)
from .settings import (DEFAULT_FORCE_NOISE, NEAR_BOUND_FACTOR, REBUILD_SHIFT,
                       SPOT_CHECK_INTERVAL, _bound_for, _near_bound,
                       guard_bound, guarded_momentum_quantum)
from .threads import OneThread


def md_forces(atoms):
    """The forces ``[n_atoms, 3]`` (eV/Å) the integrators kick with: ASE's
    ``atoms.get_forces(md=True)`` (which adds the forces of constraints
    with an energy, Hookean's), but the atoms' own forces where
    FixLinearTriatomic makes a molecule rigid: its ``md`` forces move the
    central atom's force onto the outer two for RATTLE's variables, which
    changes the molecule's total force (by 29% at the start of ASE's
    acetonitrile dimer); a rigid body takes the sum and torque of its
    atoms' own."""
    # Most runs have no constraint: one test of the list, not a loop
    # (the loop cost 0.34 µs a cached force call of Ar13; this, nothing
    # measurable).
    constraints = atoms.constraints
    if constraints and any(isinstance(c, FixLinearTriatomic)
                           for c in constraints):
        return atoms.get_forces(apply_constraint=False)
    return atoms.get_forces(md=True)


class SpotCheck:
    """Now and then, forces recomputed where the run has been, compared.

    The probe at construction moves the atoms away and back a few times;
    a calculator whose sums change from call to call (threads, GPUs,
    reductions in a varying order) can pass it by luck.  So once every
    ``interval`` force calls the positions, cell and forces are kept, and
    half an interval later, when the calculator has moved on, the forces at
    the kept positions and cell are computed again and handed to the
    provider's :meth:`~TrustedForces.compare_visit`, which raises if they
    betray a history.  Costs one force call per ``interval`` (and, for
    asap3, two neighbour-list rebuilds).  A guarded provider's clean
    recomputation makes the same kind of comparison and starts the
    interval again (:meth:`restart`).

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

    def restart(self):
        """Forces were just compared at positions the calculator had moved
        on from (a clean recomputation does that): the interval starts
        again, and a kept visit is dropped."""
        self._kept = None
        self._countdown = self.interval

    def due(self) -> bool:
        """Counts a force call; whether it is one that keeps or checks."""
        self._countdown -= 1
        return self._countdown <= 0

    def visit(self, provider, atoms):
        """The forces at the present positions, keeping or checking."""
        half = self.interval // 2
        if self._kept is None:
            f_nc = provider.evaluate(atoms)
            # The cell too: a dynamics at constant pressure moves it.
            self._kept = (atoms.positions.copy(), np.array(f_nc),
                          atoms.cell.array.copy())
            self._countdown = half
            return f_nc
        x_kept, f_kept, cell_kept = self._kept
        self._kept = None
        self._countdown = self.interval - half
        x_now = atoms.positions.copy()
        cell_now = atoms.cell.array.copy()
        atoms.positions = x_kept
        atoms.cell.array[:] = cell_kept
        try:
            f_again = provider.evaluate(atoms)
        finally:
            atoms.positions = x_now
            atoms.cell.array[:] = cell_now
        self.checks += 1
        provider.compare_visit(atoms, f_kept, np.array(f_again), half)
        return provider.evaluate(atoms)


class TrustedForces:
    """Forces used as the calculator returns them.

    ``spot_check`` (a :class:`SpotCheck`, or None) checks during runs that
    the forces stay a function of the positions; ``holds`` are the
    contexts held around chosen force calls (see :meth:`hold`).
    """

    mode = 'trust'
    force_noise = 0.0
    spot_check = None
    #: ``((context, calls), ...)``: what :meth:`hold` put in place.
    holds = ()
    #: The methods that call the calculator.
    _calculator_calls = ('forces',)

    def hold(self, context, calls=None):
        """Run the calculator calls named in ``calls`` (default: every
        method of this provider that calls the calculator) inside
        ``context()``: OpenMP and BLAS held to one thread
        (:class:`~.threads.OneThread`), deterministic torch kernels
        (:class:`~.deterministic.DeterministicKernels`).

        The methods are wrapped on this instance, so a provider without a
        hold pays nothing for it.
        """
        calls = self._calculator_calls if calls is None else tuple(calls)
        unknown = set(calls) - set(self._calculator_calls)
        if unknown:
            raise ValueError(f'{type(self).__name__} calls the calculator '
                             f'in {self._calculator_calls}, not in '
                             f'{sorted(unknown)}')
        self.holds = self.holds + ((context, calls),)
        for name in calls:
            setattr(self, name, _held(getattr(self, name), context))

    def held(self, kind):
        """The first context of class ``kind`` this provider holds around
        its force calls, or None."""
        return next((context for context, _ in self.holds
                     if isinstance(context, kind)), None)

    @property
    def one_thread(self):
        """The :class:`~.threads.OneThread` held around the force calls,
        or None."""
        return self.held(OneThread)

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
        return md_forces(atoms)

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
        f_nc = md_forces(atoms)
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
        return md_forces(atoms)


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
    _calculator_calls = ('forces', 'clean_forces')

    def __init__(self, force_noise: float = DEFAULT_FORCE_NOISE):
        self.force_noise = checked_positive(force_noise, 'force_noise', 'eV/Å')
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
        if self.spot_check is not None:
            # The comparison a spot check would make, just made: at
            # asap3's clean rate (0.5% of Cu4000's steps) most of the spot
            # checks' two force calls and two list rebuilds are saved.
            self.spot_check.restart()
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
        return guard_bound(self.force_noise, extent, f_max)

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
                md_forces(atoms)
        finally:
            atoms.positions = x_nc
        self.clean_recomputations += 1
        self._clean_nc = md_forces(atoms)
        return self._clean_nc

    def _record_noise(self, atoms, noise, bound, calls=None):
        """Keep the largest noise seen; raise if it broke the bound (an
        earlier kick may then have been rounded from noisy forces), warn
        once when it comes near it (within ``NEAR_BOUND_FACTOR``).
        ``calls``: how many force calls apart the two forces were (a spot
        check), or None (a clean recomputation)."""
        noise = float(noise)
        self.max_observed_noise = max(self.max_observed_noise, noise)
        if not _near_bound(noise, bound):
            return
        # The bound is force_noise scaled by max|F| and the extent: the
        # force_noise to pass is the noise scaled back the same way.
        wanted = _bound_for(noise * self.force_noise / bound)
        if not noise <= bound:
            raise ImpureForcesError(_spot_check_advice(
                atoms.calc, self.mode, noise, calls, bound, wanted))
        if not self._warned:
            self._warned = True
            warn_at_user_line(
                f'Force noise of {noise:.3g} eV/Å was observed, more than '
                f'1/{NEAR_BOUND_FACTOR:g} of the bound of {bound:.3g} eV/Å '
                f'(force_noise={self.force_noise:.3g} eV/Å, scaled by the '
                "coordinates' extent and max|F|) that exact reversal relies "
                'on: the run is still exact, but larger noise later would '
                'stop it. Construct the integrator with '
                f'force_noise={wanted:.2g} (eV/Å, sixteen times what was '
                'seen).', RuntimeWarning)

    def min_momentum_quantum(self, n_atoms, max_kick_time, extent=0.0):
        return guarded_momentum_quantum(n_atoms, self.force_noise,
                                        max_kick_time, extent)

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
        return md_forces(atoms)


def _held(method, context):
    """``method`` run inside ``context()``."""
    def held(*args, **kwargs):
        with context():
            return method(*args, **kwargs)
    held.__doc__ = method.__doc__
    return held
