"""ReversibleIsotropicNPT: constant pressure and temperature, run back
exactly.

The package: :mod:`.system` (the exact variables in scaled coordinates,
what the atoms show, the drift, kicks and piston), :mod:`.friction` (the
O step on the atoms and the piston), :mod:`.isotropic` (the integrator).

Andersen's barostat (H. C. Andersen, "Molecular dynamics simulations at
constant pressure and/or temperature", J. Chem. Phys. 72, 2384 (1980)) as
an extended Hamiltonian in scaled variables.  The cell is ``lambda *
cell0`` (``cell0`` the cell at construction, kept in the restart record),
the atoms sit at ``x = lambda * rho`` and carry ``p = pi / lambda``.  The
exact variables are the scaled positions ``rho`` ('position', Å), their
conjugate momenta ``pi = lambda p`` ('momentum'), the linear scale
``lambda`` ('barostat_position', dimensionless) and its momentum
``p_lambda`` ('barostat_momentum', eV ASE time).  The linear scale, not the
volume, is the coordinate: ``V = lambda**3 V0`` then takes multiplications
only, which give the same bits on every CPU (a cube root or a power would
not, see :mod:`ase_reversible.core.portable`).

The Hamiltonian is::

    H = sum pi**2 / (2 m lambda**2) + U(lambda rho, lambda cell0)
        + P V0 lambda**3 + p_lambda**2 / (2 W) - 2 kT ln lambda

The last term makes the invariant measure the isothermal-isobaric one:
with the momenta at temperature ``T``, ``exp(-H / kT)`` integrated over
``p_lambda`` carries the factor ``lambda**2``, and ``lambda**2 d lambda =
dV / (3 V0)``; ``d rho d pi = dx dp`` because the two Jacobians
(``lambda**3N`` and ``lambda**-3N``) cancel.  The stationary density is
then ``exp(-(K + U + P V) / kT) dx dp dV``, the ensemble ASE's MTK
integrators target.

``H`` splits into three parts, each of whose flows is a shear (it adds to
some variables a function of variables it leaves alone), so each is made
exact as the drift and kick of :mod:`.hamiltonian` are:

* ``T = sum pi**2 / (2 m lambda**2)``: ``rho += h pi / (m lambda**2)``
  and ``p_lambda += h 2K / lambda`` (``K`` the kinetic energy);
* ``U + P V - 2 kT ln lambda``: ``pi += h lambda F(x)`` and ``p_lambda +=
  h G`` with ``G = -dU/dlambda - 3 P V0 lambda**2 + 2 kT / lambda``.  At
  fixed ``rho`` a change of ``lambda`` strains the periodic system
  uniformly by ``d lambda / lambda``, and ASE's stress is ``sigma = (1/V)
  dU/d(strain)``, so ``-dU/dlambda = -V tr(sigma) / lambda`` and ``G =
  -lambda**2 V0 (tr(sigma) + 3P) + 2 kT / lambda``
  (``tests/test_npt.py`` checks this against finite differences of the
  energy under a uniform scaling);
* ``p_lambda**2 / (2W)``: ``lambda += h p_lambda / W``.

The temperature is held by Langevin's O step on ``pi`` (whose mass is
``m lambda**2``, ``lambda`` being fixed during it), made exact as in
:mod:`.langevin`: friction through the information buffer, noise from the
counter-based generator.  Its friction is ``1 / tdamp``.  The same O step
gives the piston a friction ``1 / pdamp`` and noise of its own (a Langevin
piston, holding ``p_lambda`` at ``exp(-p_lambda**2 / 2WkT)``, which leaves
the ensemble as it is): it decorrelates the volume sooner.  Measured on
256 Cu atoms (asap3 EMT, 300 K, P = 0, dt 5 fs, tdamp 100 fs, pdamp 500
fs, two seeds of 20,000 steps each, the first 2,000 left out): the
volume oscillates with a period of 19 steps under either; the envelope of
its autocorrelation falls below 1/e after 180 steps without the piston's
friction and after 100-120 with it, and the sum of the squared
autocorrelation over 1,000 lags is 42-50 without and 26-30 with, at the
same spread of the volume (9.8-10.5 Å**3 of 3022).  Its deviate is drawn
with the atoms' (a draw of its own would cost 120 us a step; with the
atoms', the piston's part of the O step costs 30 us, timeit on 32 atoms
under load 4.5).  One step is the palindrome ``B/2 P/2 T/2 O T/2 P/2 B/2``
(B the ``U`` part, P the piston, T the kinetic part), with one force and
stress call, at the step's end as in velocity Verlet.

The barostat's mass.  ASE's ``IsotropicMTKNPT`` moves ``eps = ln(V/V0) / 3
= ln lambda`` with the mass ``W_eps = (3N + 3) kT pdamp**2``, so that the
volume oscillates with a period of the order of ``pdamp``.  The kinetic
energy ``W_eps (d eps/dt)**2 / 2 = W_eps (d lambda/dt)**2 / (2 lambda**2)``
equals ``W (d lambda/dt)**2 / 2`` at the construction volume for ``W =
W_eps``: that is the ``W`` used (``lambda`` stays near 1, the volume
moving by a few per cent).

Only fully periodic cells are supported: for a cluster ``-dU/dlambda``
would be the virial ``sum x.F / lambda``, and ``V`` has no meaning.

Gradients.  Each sub-step has its adjoint rule.  The piston's push ``G``
needs its derivative in ``rho``, the stress's derivative in the
positions, which no calculator offers; but ``dG/d rho = -d2U/(d rho d
lambda) = d(lambda F)/d lambda``, so it is the central difference of
``lambda F`` in ``lambda`` (positions and cell scaled together), which
also gives the kick's derivative in ``lambda``; the same two calls give
``dG/d lambda`` from the stress.  The O step's noise scales with
``lambda``: its derivative ``n`` (the noise at ``lambda = 1``) enters
``a_lambda``.  The friction's rounding (the buffer's digits) is left out,
as for :class:`~ase_reversible.ReversibleLangevin`.
"""

from .isotropic import ENERGY_CHECK_INTERVAL, SCHEME, ReversibleIsotropicNPT
from .system import (LAMBDA_MIN, LAMBDA_QUANTUM, P_LAMBDA_BITS,
                     NPTHamiltonian, VirialKick, barostat_mass, cell_volume)

__all__ = ['ReversibleIsotropicNPT', 'NPTHamiltonian', 'VirialKick',
           'cell_volume', 'barostat_mass', 'LAMBDA_MIN', 'LAMBDA_QUANTUM',
           'P_LAMBDA_BITS', 'SCHEME', 'ENERGY_CHECK_INTERVAL']
