"""The rules of Nosé's thermostat that every driver shares (the ASE
integrator, :mod:`ase_reversible.lammps.nose` and the compiled fix it
passes them to): the thermostat's mass, the quanta of ``s``, ``pi`` and the
clock, the degrees of freedom, and the chain's confinement.  Pure
functions of numbers in any consistent units."""

from __future__ import annotations

import math

from ...core.codec import power_of_two_below
from ...core.portable import dot

#: Confinement of the chain's coordinates ``s_j``, ``j >= 2``: each has the
#: potential ``kT (a (s - 1) - (a - 1) ln s)`` (docs/thermostats.md,
#: "A chain of thermostats"), which
#: gives it the weight ``s**a exp(-a (s - 1))``, largest at ``s = 1``.
CHAIN_STIFFNESS = 4.0

#: Centre-of-mass kinetic energy (in kT) above which unconstrained atoms
#: are warned about: a thermal centre of mass has 1.5 kT, one at rest
#: (``Stationary``) a few momentum quanta.
CENTRE_OF_MASS_TOLERANCE = 0.01

#: Quantum of ``s`` (dimensionless, starts at 1): 2**-40 leaves 2**12 of
#: range above 1 and resolves an increment of ``h pi / Q`` to 2**-40.
S_QUANTUM = 2.0**-40
#: Bits of ``sqrt(Q kT)`` (the spread of ``pi``) below its quantum.
PI_BITS = 40
#: Bits of ``|dt|`` below the clock's quantum: the clock rounds each half
#: step to 2**-24 of the time step and runs for 2**28 steps of ``|dt|``
#: before its counts reach 2**53.
CLOCK_BITS = 24
#: Virtual momentum counts below this are recovered exactly from a
#: frame's momenta ``p' / s`` and ``s`` (two roundings of 2**-53 each);
#: above, the record stores them.
RECOVERABLE = 2.0**50


def thermostat_mass(g, kT, tdamp):
    """Nosé's ``Q = g kT tdamp**2``, energy x time**2 (eV (ASE time)**2
    for ``kT`` in eV and ``tdamp`` in ASE time units): the thermostat's
    period is of the order of ``tdamp``."""
    return g * kT * (tdamp * tdamp)


def chain_masses(g, kT, tdamp, tchain):
    """``[Q_1, ..., Q_M]``, eV (ASE time)**2: ``Q_1 = g kT tdamp**2`` and
    ``kT tdamp**2`` for the others, as ASE's ``NoseHooverChainNVT`` sets
    its chain's masses."""
    return [thermostat_mass(g if j == 0 else 1, kT, tdamp)
            for j in range(tchain)]


def confinement(kT, s, a=None):
    """``phi(s) = kT (a (s - 1) - (a - 1) ln s)``, eV: the potential of a
    chain coordinate after the first."""
    a = CHAIN_STIFFNESS if a is None else a
    return kT * (a * (s - 1.0) - (a - 1.0) * math.log(s))


def confinement_force(kT, s, a=None):
    """``phi'(s) = kT (a - (a - 1) / s)``, eV."""
    a = CHAIN_STIFFNESS if a is None else a
    return kT * (a - (a - 1.0) / s)


def confinement_curvature(kT, s, a=None):
    """``phi''(s) = kT (a - 1) / s**2``, eV."""
    a = CHAIN_STIFFNESS if a is None else a
    return kT * (a - 1.0) / (s * s)


def pi_quantum(Q, kT):
    """The quantum of a thermostat momentum ``pi`` of mass ``Q`` at ``kT``
    (energy x time): ``PI_BITS`` bits below the power of two at or below
    its spread ``sqrt(Q kT)``."""
    return math.ldexp(power_of_two_below(math.sqrt(Q * kT)), -PI_BITS)


def clock_quantum(timestep):
    """The quantum of the real-time clock (time unit of ``timestep``):
    ``CLOCK_BITS`` bits below the power of two at or below ``|timestep|``."""
    return math.ldexp(power_of_two_below(abs(timestep)), -CLOCK_BITS)


def free_degrees_of_freedom(n_atoms, dimension=3, centre_at_rest=True):
    """``N_f`` of ``n_atoms`` free atoms in ``dimension`` dimensions.

    ``d N - d`` where the centre of mass is at rest: the forces conserve
    the total momentum, so zero stays zero and the thermostat has nothing
    to scale there (LAMMPS's fix nvt always counts so: its temperature
    compute removes ``d``).  ``d N`` where it moves: Nosé's scaling acts on
    the total momentum too, so the centre is one more thermostatted set of
    ``d`` (ASE's ``NoseHooverChainNVT`` counts ``3N`` always).
    """
    return dimension * n_atoms - (dimension if centre_at_rest else 0)


def centre_at_rest(momentum_c, total_mass, kT):
    """Whether a total momentum ``momentum_c`` ``[3]`` (amu Å / ASE time)
    of atoms of ``total_mass`` (amu) is at rest at ``kT`` (eV): its kinetic
    energy at most :data:`CENTRE_OF_MASS_TOLERANCE` kT, as ``Stationary``
    leaves it (a few momentum quanta); a thermal centre has 1.5 kT."""
    drift = 0.5 * dot(momentum_c, momentum_c) / total_mass
    return drift <= CENTRE_OF_MASS_TOLERANCE * kT
