"""The demo: a hot argon cluster run forward, reversed, and back to the bit.

Run it with ``python -m ase_reversible demo``.  It prints the bit-for-bit
verdict of ReversibleVerlet, the error VelocityVerlet makes on the same
round trip, the force calls each made, and the energy behaviour of both over
the forward run.  Nothing it prints depends on how busy the machine is: cost
is counted in force calls, not seconds.
"""

from __future__ import annotations

import argparse
import math

import numpy as np
from ase import units
from ase.md.verlet import VelocityVerlet

from ..md import ReversibleVerlet
from .systems import ICOSAHEDRON_SHELLS, argon_cluster, argon_lj


def make_cluster(n_atoms, temperature_K, seed):
    """Ar``n_atoms`` icosahedron (a key of ``ICOSAHEDRON_SHELLS``) in 10 Å
    of vacuum, momenta at exactly ``temperature_K`` K drawn from ``seed``,
    with ASE's LennardJones (argon parameters) attached."""
    atoms = argon_cluster(ICOSAHEDRON_SHELLS[n_atoms], temperature_K, seed)
    atoms.calc = argon_lj()
    return atoms


def count_calculations(calc):
    """Count the calculator's ``calculate`` calls from now on.

    Counting at the calculator, not in the integrators, counts what each
    integrator really costs: its set-up and probes included, and force
    requests answered from the calculator's cache excluded.
    """
    counter = [0]
    calculate = calc.calculate

    def counted(*args, **kwargs):
        counter[0] += 1
        return calculate(*args, **kwargs)

    calc.calculate = counted
    return counter


def energy_record(dyn, steps):
    energies = []
    dyn.attach(lambda: energies.append(dyn.atoms.get_total_energy()))
    dyn.run(steps)
    dyn.observers.clear()
    return np.array(energies)


def describe(energies, dt):
    e0 = energies[0]
    t = np.arange(len(energies)) * dt / (1000 * units.fs)  # ps
    slope = np.polyfit(t, energies - e0, 1)[0] if len(t) > 1 else 0.0
    return (f'std {np.std(energies):.2e} eV   max|E-E0| '
            f'{np.abs(energies - e0).max():.2e} eV   drift {slope:+.1e} eV/ps')


def exponent(q):
    return math.frexp(q)[1] - 1


def main(argv=None, prog='ase-reversible demo'):
    parser = argparse.ArgumentParser(
        prog=prog,
        description='Reverse a hot argon cluster bit for bit.')
    parser.add_argument('--atoms', type=int, default=147,
                        choices=sorted(ICOSAHEDRON_SHELLS))
    parser.add_argument('--steps', type=int, default=1000)
    parser.add_argument('--temperature', type=float, default=120.0,
                        help='initial temperature, K (default 120)')
    parser.add_argument('--timestep', type=float, default=5.0,
                        help='fs (default 5)')
    parser.add_argument('--seed', type=int, default=0)
    args = parser.parse_args(argv)
    dt = args.timestep * units.fs
    n = args.steps

    print(f'ase-reversible demo: Ar{args.atoms} icosahedron at '
          f'{args.temperature:g} K, ASE LennardJones, dt = '
          f'{args.timestep:g} fs, {n} steps forward then {n} back')

    atoms = make_cluster(args.atoms, args.temperature, args.seed)
    calls_rev = count_calculations(atoms.calc)
    dyn = ReversibleVerlet(atoms, dt)
    g = dyn.grid
    print(f'grid: position quantum 2^{exponent(g.position_quantum)} Å '
          f'({g.position_quantum:.2e} Å, range ±{g.position_range:.3g} Å); '
          f'momentum quantum 2^{exponent(g.momentum_quantum)} '
          f'({g.momentum_quantum:.2e} amu Å/ASE time, range '
          f'±{g.momentum_range:.3g})')
    x0, p0 = atoms.get_positions(), atoms.get_momenta()
    e_rev = energy_record(dyn, n)
    dyn.reverse()
    dyn.run(n)
    exact = (np.array_equal(atoms.positions, x0)
             and np.array_equal(atoms.get_momenta(), p0))

    twin = make_cluster(args.atoms, args.temperature, args.seed)
    twin.set_positions(x0)
    twin.set_momenta(p0)
    calls_vv = count_calculations(twin.calc)
    vv = VelocityVerlet(twin, dt)
    e_vv = energy_record(vv, n)
    vv.dt = -dt
    vv.run(n)
    err_x = np.abs(twin.positions - x0).max()
    err_p = np.abs(twin.get_momenta() - p0).max()

    rev_x = np.abs(atoms.positions - x0).max()
    rev_p = np.abs(atoms.get_momenta() - p0).max()

    print()
    print(f'Round trip ({n} steps forward, then {n} with the time step '
          'negated; |dp| in amu Å/ASE time):')
    verdict = 'YES, bit for bit' if exact else 'NO'
    print(f'  ReversibleVerlet back at the start: {verdict} '
          f'(max |dx| = {rev_x:.1e} Å, max |dp| = {rev_p:.1e})')
    print(f'  VelocityVerlet   back at the start: '
          f'{"YES" if err_x == 0 and err_p == 0 else "no"} '
          f'(max |dx| = {err_x:.1e} Å, max |dp| = {err_p:.1e})')
    print()
    print(f'Force calls ({2 * n} steps each, set-up included):')
    print(f'  ReversibleVerlet  {calls_rev[0]}')
    print(f'  VelocityVerlet    {calls_vv[0]}')
    print()
    print(f'Total energy over the forward run ({n} steps):')
    print(f'  ReversibleVerlet  {describe(e_rev, dt)}')
    print(f'  VelocityVerlet    {describe(e_vv, dt)}')
    return 0 if exact else 1
