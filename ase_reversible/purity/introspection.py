"""What a calculator is, what it mixes, and how to make it forget."""

from __future__ import annotations

import sys


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


def discard_all_results(calc):
    """:func:`discard_results` for ``calc`` and every calculator it mixes:
    a mixing calculator's members keep their own results, which it would
    otherwise sum again at positions they were computed at."""
    for c in calculator_members(calc):
        discard_results(c)


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


def torch_modules(calc):
    """The ``torch.nn.Module`` objects ``calc`` and the calculators it mixes
    hold: among their attributes, and one level down inside lists, tuples
    and dicts among them (MACE's calculator keeps ``.models``, a list;
    others keep ``.model``).  Returns a list, each module once.  A
    calculator that declares ``holds_deterministic_kernels = True``
    (:class:`~ase_reversible.torch.TorchCalculator`) holds them around
    its own calls and is left out: it is probed as any other.

    Never imports torch: with no torch loaded, nothing can hold a module.
    """
    torch = sys.modules.get('torch')
    module_class = getattr(getattr(torch, 'nn', None), 'Module', None)
    if module_class is None:
        return []
    found = {}
    for c in calculator_members(calc):
        if getattr(c, 'holds_deterministic_kernels', False) is True:
            continue
        for value in getattr(c, '__dict__', {}).values():
            inner = (value.values() if isinstance(value, dict) else
                     value if isinstance(value, (list, tuple)) else ())
            for candidate in (value, *inner):
                if isinstance(candidate, module_class):
                    found.setdefault(id(candidate), candidate)
    return list(found.values())


def torch_devices(modules):
    """The devices (``torch.device``) of the parameters and buffers of
    ``modules`` (torch modules), each once."""
    devices = {}
    for module in modules:
        for tensor in (*module.parameters(), *module.buffers()):
            devices.setdefault(str(tensor.device), tensor.device)
    return list(devices.values())


def torch_precisions(modules):
    """The floating-point dtypes (``torch.dtype``) of the parameters and
    buffers of ``modules`` (torch modules), each once."""
    dtypes = {}
    for module in modules:
        for tensor in (*module.parameters(), *module.buffers()):
            if tensor.is_floating_point():
                dtypes.setdefault(str(tensor.dtype), tensor.dtype)
    return list(dtypes.values())
