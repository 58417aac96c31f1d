"""Argument checks of the ASE adapters: refuse bad input before anything
is changed or opened, with a message that says what to do."""

from __future__ import annotations

import math

import numpy as np
from ase import units
from ase.constraints import FixCom, FixedLine, FixedPlane

from ..core.arguments import checked_positive
from ..core.infobuffer import DIGIT_BITS
from ..core.quanta import momentum_resolution_problem
from ..core.record import INFO_KEY
from ..errors import CoarseQuantumError, UnsupportedConstraintError
from ..purity import DEFAULT_FORCE_NOISE


def check_timestep(timestep):
    """The time step as a finite, non-zero float (ASE time units)."""
    if isinstance(timestep, (str, bytes)):
        raise TypeError(f'timestep must be a number (ASE time units, e.g. '
                        f'5 * ase.units.fs), got the string {timestep!r}')
    try:
        dt = float(timestep)
    except (TypeError, ValueError):
        raise TypeError(f'timestep must be a number (ASE time units, e.g. '
                        f'5 * ase.units.fs), got {timestep!r}') from None
    if not math.isfinite(dt) or dt == 0:
        raise ValueError(f'timestep must be finite and non-zero (ASE time '
                         f'units, e.g. 5 * ase.units.fs), got {timestep!r}')
    return dt


#: K.  A target temperature below this is ``kB T`` in eV, the unit of
#: ASE's deprecated ``temperature`` (its third positional argument in
#: ``Langevin`` and ``NVTBerendsen``): 300 K is 0.0259 eV, and anything
#: below 11604 K is below 1 in eV.
EV_LIKE_BELOW = 1.0


def check_temperature_K(temperature_K, dynamics, temperature=None):
    """The target temperature (K) of ``dynamics`` (a class name), checked.

    ASE's deprecated ``temperature`` (eV) is refused with its translation,
    and so is a ``temperature_K`` below :data:`EV_LIKE_BELOW`: it is what
    ASE's positional call ``Langevin(atoms, dt, kB * T, friction)`` passes
    in the third place, and taken as kelvin it would run 11604 times
    colder than meant.
    """
    if temperature is not None:
        hint = (f'temperature_K={temperature / units.kB:.6g}'
                if isinstance(temperature, (int, float)) else
                'temperature_K=temperature / ase.units.kB')
        raise TypeError(
            f'{dynamics} takes the temperature in kelvin: temperature= is '
            f'ASE\'s deprecated temperature in eV. Pass {hint} instead.')
    if temperature_K is None:
        raise TypeError(f'{dynamics} needs temperature_K, the target '
                        'temperature in kelvin (e.g. temperature_K=300).')
    value = checked_positive(temperature_K, 'temperature_K', 'K')
    if value < EV_LIKE_BELOW:
        raise ValueError(
            f'{dynamics} got a target temperature of {value:g}, below '
            f'{EV_LIKE_BELOW:g} K: that is kB T in eV, the unit of ASE\'s '
            f'deprecated positional temperature, for {value / units.kB:.6g} '
            f'K. Pass temperature_K={value / units.kB:.6g} (in kelvin). '
            f'Targets below {EV_LIKE_BELOW:g} K are refused, being eV far '
            'more often than meant.')
    return value


def check_steps(steps):
    """A whole number of steps >= 0."""
    if isinstance(steps, bool) or not isinstance(steps, (int, np.integer)) \
            or steps < 0:
        raise ValueError(f'steps must be a whole number >= 0, got {steps!r}')
    return int(steps)


def check_energy_watch(interval, tolerance):
    """``(energy_check, energy_tolerance)`` of the energy check, checked."""
    if isinstance(interval, bool) or not isinstance(interval, int) \
            or interval < 0:
        raise ValueError(f'energy_check must be a whole number of steps '
                         f'(0 turns the check off), got {interval!r}')
    if tolerance is not None:
        tolerance = float(tolerance)
        if not tolerance > 0:
            raise ValueError(f'energy_tolerance must be positive (eV), got '
                             f'{tolerance!r}')
    return interval, tolerance


def refuse_calculator_without_forces(calc, doing):
    """Refuse a missing calculator or one that only holds stored results
    (``doing``: what the message says it is needed for)."""
    if calc is None:
        raise RuntimeError(f'The atoms have no calculator: attach one '
                           f'(atoms.calc = ...) before {doing}.')
    from ase.calculators.singlepoint import SinglePointCalculator
    if isinstance(calc, SinglePointCalculator):
        raise RuntimeError(
            'The atoms carry a SinglePointCalculator: the stored results of '
            'a trajectory frame, which cannot compute forces anywhere else. '
            f'Attach a real calculator (atoms.calc = ...) before {doing}; '
            "the frame's positions, momenta and restart record are kept.")


def checked_masses(atoms):
    """The masses ``[n_atoms]`` (amu), refused unless positive and finite."""
    masses_n = atoms.get_masses()
    bad = ~(masses_n > 0) | ~np.isfinite(masses_n)
    if np.any(bad):
        atom = int(np.argwhere(bad)[0, 0])
        raise ValueError(f'Atom {atom} has mass {float(masses_n[atom])}: '
                         'every mass must be positive and finite (set it '
                         'with atoms.set_masses).')
    return masses_n


def fixed(name):
    """Refuse an assignment to something fixed at construction."""
    raise AttributeError(
        f'The {name} of a reversible integrator is fixed when it is '
        'constructed; '
        'construct a new one (from the present atoms, which hold the exact '
        'state and its restart record) to change it.')


def refuse_coarse_momentum_quantum(masses_n, momenta_nc, grid, origin,
                                   purity):
    """Refuse a momentum quantum that would visibly change the momenta.

    ``momenta_nc`` ``[n_atoms, 3]`` already projected onto the
    constraints; ``origin`` as returned by
    :func:`ase_reversible.core.quanta.choose_grid`.
    """
    qp = grid.momentum_quantum
    problem = momentum_resolution_problem(masses_n, momenta_nc, qp)
    if problem is None:
        return
    source, remedy = {
        'given': ('as given', 'Pass a finer momentum_quantum, or none '
                  '(the default is chosen for these momenta).'),
        'record': ('from the restart record in atoms.info',
                   'Remove the record (atoms.info.pop('
                   f'{INFO_KEY!r})) to start a new run on a grid chosen '
                   'for these momenta.'),
        'default': ('chosen by default', 'Pass a finer momentum_quantum.'),
        'purity': (f"raised to this by force_purity='{purity.mode}' with "
                   f'force_noise={purity.force_noise:.3g} eV/Å, which '
                   'keeps clean recomputations of the forces rare',
                   'force_noise bounds the history noise of the '
                   'forces; neighbour lists leave noise below 1e-12 '
                   'eV/Å (the default bound is '
                   f'{DEFAULT_FORCE_NOISE:.2g}). A '
                   'bound this large means the noise comes from state '
                   'the calculator carries between calls, such as a '
                   'self-consistent field: make each calculation start '
                   "from scratch and use force_purity='auto'. A "
                   'smaller force_noise or time step also gives a '
                   'finer quantum.'),
    }[origin]
    raise CoarseQuantumError(
        f'The momentum quantum {qp:.3g} amu Å / ASE time unit '
        f'({source}) is too coarse: {problem}. {remedy} Nothing was '
        'changed.')


def checked_friction(friction, timestep):
    """A thermostat's friction (1 / ASE time unit) as a float: 0 (none), or
    positive with ``exp(-friction |timestep|)`` between ``2**-16`` and
    below 1 in float64."""
    unit = '1 / ASE time unit, e.g. 0.01 / ase.units.fs'
    try:
        friction = float(friction)
    except (TypeError, ValueError):
        raise TypeError(f'friction must be a number ({unit}), got '
                        f'{friction!r}') from None
    if friction == 0:
        return 0.0  # NVE, as ASE's Langevin allows
    friction = checked_positive(friction, 'friction', f'{unit}; 0 for '
                                'no thermostat')
    if math.exp(-friction * abs(timestep)) == 1.0:
        raise ValueError(
            f'friction * |timestep| is {friction * abs(timestep):.3g}, too '
            'small to change a momentum (exp(-friction |timestep|) is 1 in '
            'float64): pass friction=0 for no thermostat.')
    if friction * abs(timestep) > DIGIT_BITS * math.log(2):
        raise ValueError(
            f'friction * |timestep| is {friction * abs(timestep):.3g}; at '
            f'most {DIGIT_BITS * math.log(2):.3g} is supported (the momenta '
            'keep a 2**-16 of themselves per step). Momenta that are '
            'reset every step are not dynamics: use a smaller friction or '
            'time step.')
    return friction


def checked_seed(seed):
    """The noise's seed as an int in ``[0, 2**64)``; None draws one."""
    if seed is None:
        return int(np.random.SeedSequence().entropy % 2**64)
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)):
        raise TypeError(f'seed must be an int, got {seed!r}')
    return int(seed) % 2**64


def seed_from(seed, rng, dynamics):
    """The seed of ``dynamics`` (a class name): ``seed`` as given, or one
    drawn from ``rng`` (ASE's argument: a numpy Generator, a RandomState
    or the ``numpy.random`` module) with a single draw in ``[0, 2**63)``,
    so the same seeded generator gives the same run; None if neither
    (:func:`checked_seed` draws one).  Both given: ValueError."""
    if rng is None:
        return seed
    if seed is not None:
        raise ValueError(
            f'{dynamics} got both seed={seed!r} and rng: pass one (rng is '
            'used once, to draw the seed).')
    if isinstance(rng, np.random.Generator):
        return int(rng.integers(2**63))
    if isinstance(rng, np.random.RandomState) or rng is np.random:
        return int(rng.randint(2**63, dtype=np.int64))
    raise TypeError(
        f'rng must be a numpy Generator (numpy.random.default_rng(...)), a '
        f'numpy.random.RandomState or the numpy.random module, got '
        f'{rng!r}; for an integer, pass seed= instead.')


def refuse_plane_and_line_constraints(atoms, name='ReversibleLangevin',
                                      what='the friction and noise'):
    """Refuse FixedPlane and FixedLine, which ``what`` of dynamics
    ``name`` (a class name) is not projected onto."""
    centred = any(isinstance(c, FixCom) for c in atoms.constraints)
    for c in atoms.constraints:
        if isinstance(c, (FixedPlane, FixedLine)):
            raise UnsupportedConstraintError(
                f'{name} supports FixAtoms, FixCartesian and '
                f'FixCom; {type(c).__name__} would need {what} '
                'projected onto it, which is not done yet. Use '
                'FixCartesian where the constraint is along an axis, or '
                'ReversibleNose (constant temperature) or ReversibleVerlet '
                '(constant energy), which support it'
                + (' without FixCom (zero the net momentum once with '
                   'ase.md.velocitydistribution.Stationary instead).'
                   if centred else '.'))
