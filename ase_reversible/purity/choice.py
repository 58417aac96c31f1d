"""The choice of a force provider for a calculator (``force_purity``)."""

from __future__ import annotations

from contextlib import nullcontext

import numpy as np

from ..core.kernels import cublas_problem, prepare_cublas, steady_torchscript
from ..errors import ImpureForcesError
from .advice import (_cublas_advice, _impurity_advice, _parallel_noise_advice,
                     _run_to_run, _torch_advice)
from .deterministic import DeterministicKernels
from .introspection import (_declares_pure, _is_asap3,
                            _is_ase_neighborlist_calculator,
                            _is_plain_ase_neighborlist_calculator, _mixes,
                            calculator_members, discard_all_results,
                            torch_devices, torch_modules, torch_precisions)
from .probe import (measured_force_noise, noise_as_force_noise, probe_purity,
                    repeat_noise)
from .providers import (ColdStartForces, GuardedForces,
                        SortedNeighborListForces, SpotCheck, TrustedForces)
from .settings import DEFAULT_FORCE_NOISE, SUMMATION_NOISE_LIMIT
from .threads import one_thread, uses_openmp


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
        takes ``'cold-start'`` if that makes them pure; noise left at the
        level of rounding is probed once more with OpenMP and BLAS held to
        one thread, which removes the noise of parallel sums; otherwise it
        refuses the calculator.  A calculator that holds torch modules
        (:func:`~.introspection.torch_modules`) is probed as it is, then
        under deterministic torch kernels, which it keeps if they make it
        pure: around a guarded provider's clean recomputations only if the
        noise without them is small enough for the guard, else around
        every call (see the torch section of docs/force-purity.md).  A refusal says whether
        the noise varies between calls repeated at the same positions
        (run-to-run nondeterminism) or with history.  In every mode, a
        calculator known to sum in OpenMP threads
        (:data:`~.threads.OPENMP_CALCULATOR_PACKAGES`: tblite) has every
        force call held to one thread.
    force_noise : float, optional
        Noise bound for ``'guarded'`` (eV/Å).

    Returns
    -------
    TrustedForces, SortedNeighborListForces, GuardedForces or ColdStartForces
        Its ``holds`` are the contexts held around its force calls (its
        ``one_thread`` the thread hold, or None).  Raises
        :class:`ImpureForcesError` if ``'auto'`` probes the calculator and
        no handling removes the history noise it sees.
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
    provider = _handling(atoms, mode, force_noise)
    if provider.one_thread is None and any(
            uses_openmp(c) for c in calculator_members(atoms.calc)):
        provider.hold(one_thread())
    return provider


def _handling(atoms, mode, force_noise):
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
        elif torch_modules(calc):
            return _torch_probed(atoms, listed)
        else:
            return _probed(atoms, listed)
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


def _probed(atoms, listed):
    """The provider ``'auto'`` takes for a calculator it does not know,
    from probes; raises :class:`ImpureForcesError` if none makes the
    forces pure.

    A calculator known to sum in OpenMP threads is probed with its thread
    pools held to one thread.  Any other that shows noise at the level of
    rounding is probed again so held: the noise may be threads adding
    their partial sums in a varying order, which one thread removes.
    """
    calc = atoms.calc
    known = any(uses_openmp(c) for c in calculator_members(calc))
    held = one_thread() if known else None
    provider, refusal, rounding = _probe_choice(atoms, listed, held)
    if provider is None and rounding and held is None:
        held = one_thread()
        provider, refusal, _ = _probe_choice(atoms, listed, held)
    if provider is None:
        raise ImpureForcesError(refusal)
    if held is not None:
        provider.hold(held)
    return provider


def _probe_choice(atoms, listed, held):
    """``(provider, None, False)`` if the probes find a handling that makes
    the forces pure (under ``held``, a OneThread or None), else ``(None,
    message, rounding)``, ``rounding`` True if the noise left was at the
    level of rounding."""
    calc = atoms.calc
    with held() if held is not None else nullcontext():
        provider = _base_provider(atoms, listed)
        noise = probe_purity(atoms)
        if not noise:
            return provider, None, False
        f_max = np.abs(provider.forces(atoms)).max(initial=0.0)
        small = SUMMATION_NOISE_LIMIT * max(1.0, f_max)
        if not listed and noise > small:
            # Noise this large is state carried between calls (an SCF
            # started from its last solution): try starting cold.
            cold = ColdStartForces()
            left = probe_purity(atoms, forces=cold.forces)
            if not left:
                return cold, None, False
            if left <= small:
                return (None, _parallel_noise_advice(
                    calc, noise, left, held is not None), True)
            # Started cold, a self-consistent field repeats itself: what
            # still varies between repeated calls is not its history.
            repeated = repeat_noise(atoms, forces=cold.forces)
        else:
            repeated = repeat_noise(atoms, forces=provider.forces)
        return (None, _impurity_advice(
            calc, noise, f_max, cold_start_tried=not listed,
            one_thread_tried=held is not None, repeated=repeated),
                noise <= small)


def _torch_probed(atoms, listed):
    """The provider ``'auto'`` takes for a calculator that holds torch
    modules (:func:`~.introspection.torch_modules`); raises
    :class:`ImpureForcesError` if none makes the forces pure.

    TorchScript's profiling-guided optimisation is turned off for the
    process first (:func:`~ase_reversible.core.kernels.steady_torchscript`):
    with it, a scripted model's bits depend on how often it ran before.
    Then, by what the modules are:

    - float64 on the CPU: probed as it is; pure, it is trusted.
    - below float64 anywhere: PyTorch's deterministic kernels
      (:class:`~.deterministic.DeterministicKernels`) held around every
      call, without a plain probe first.  MACE in float32 on the CPU (two
      threads) gave forces 1e-7 eV/Å apart at the same positions in 2 of
      12 fresh probes and the same bits in the other 10, so a probe that
      saw nothing had not shown it pure; and noise that size is far beyond
      what guarded rounding absorbs.
    - float64 on another device (a GPU's atomic adds): guarded rounding
      whose clean recomputations run under deterministic kernels
      (:func:`_kernel_hold`), whether or not the plain probe saw noise.

    In every case the probe under deterministic kernels must find the
    forces pure, else the calculator is refused.
    """
    # Before the model's first CUDA call, when cuBLAS makes its workspace.
    prepare_cublas()
    steady_torchscript()
    calc = atoms.calc
    modules = torch_modules(calc)
    devices = torch_devices(modules)
    below_float64 = any(str(d) != 'torch.float64'
                        for d in torch_precisions(modules))
    off_cpu = any(d.type != 'cpu' for d in devices)
    plain = _base_provider(atoms, listed)
    noise = 0.0
    if not below_float64:
        noise = probe_purity(atoms, forces=plain.forces)
        if not noise and not off_cpu:
            return plain
    for device in devices:
        problem = cublas_problem(device)
        if problem is not None:
            raise ImpureForcesError(_cublas_advice(calc, noise, problem))
    held = _base_provider(atoms, listed)
    held.hold(DeterministicKernels())
    left = probe_purity(atoms, forces=held.forces)
    if left:
        f_max = np.abs(held.forces(atoms)).max(initial=0.0)
        repeated = repeat_noise(atoms, forces=held.forces)
        raise ImpureForcesError(
            _torch_advice(calc, left, f_max, repeated)
            if _run_to_run(left, repeated) else
            _impurity_advice(calc, left, f_max))
    if below_float64:
        return held
    return _kernel_hold(atoms, plain, held, noise, listed)


def _kernel_hold(atoms, plain, held, noise, listed):
    """The provider for forces that are pure under deterministic kernels
    (``held``, holding them around every call) and vary by ``noise`` (eV/Å)
    without them (``plain``).

    If guarded rounding with a bound measured from that noise can absorb
    it, a :class:`GuardedForces` whose clean recomputations alone are held
    to the kernels: a flagged kick is then rounded from the deterministic
    forces both ways, and the other calls pay nothing for the kernels.
    Else ``held``.
    """
    # The guard rounds from either kind of forces: its bound covers the
    # noise among the plain ones and their distance from the held ones.
    # Each computed afresh, not from the cache of the other; the held ones
    # last, so that a cached result the first step may use is theirs.
    discard_all_results(atoms.calc)
    f_plain = np.array(plain.forces(atoms))
    discard_all_results(atoms.calc)
    offset = float(np.abs(f_plain - held.forces(atoms)).max(initial=0.0))
    force_noise = noise_as_force_noise(atoms, max(noise, offset),
                                       forces=held.forces)
    # GuardedForces keeps no sorted lists: beside members that need them
    # its bound, measured with them sorted, would not hold.
    if listed or force_noise > DEFAULT_FORCE_NOISE:
        return held
    guarded = GuardedForces(force_noise)
    guarded.hold(held.held(DeterministicKernels), calls=('clean_forces',))
    return guarded


def _base_provider(atoms, listed):
    """The provider before any handling of noise: sorted lists for the
    members that keep ASE's lists (in place, so that a probe meets them),
    else the forces as returned."""
    if not listed:
        return TrustedForces()
    provider = SortedNeighborListForces(listed)
    provider.forces(atoms)
    return provider
