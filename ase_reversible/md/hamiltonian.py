"""Atoms as a Hamiltonian system in fixed point: the drift and the kick.

Positions and momenta are the exact variables ``'position'`` and
``'momentum'``, ``[n_atoms, 3]``.  The two sub-steps are shears -- each adds
the odd rounding of a function of the variable it does not change (Stam,
"An Exact Bitwise Reversible Integrator", eq. posVerlet):

* drift: ``x += round_odd(c h P p / m / q_x)``
* kick: ``p += round_odd(c h P F(x) / q_p)``

with ``P`` the constraint projection; a FixCom then balances the rounded
increments (:class:`~.constraints.FixedCentre`).  Each brings its adjoint rule
(:mod:`ase_reversible.adjoint`).
"""

from __future__ import annotations

import numpy as np
from ase import units

from ..core.codec import round_odd
from ..core.plans import SubStep, compose
from ..core.variables import ExactVariable
from .admission import encoded
from .constraints import added_force_product, no_projection
from ..errors import NonFiniteForcesError, QuantumRangeError

#: Temperature (K) whose kinetic energy is the smallest default tolerance
#: of the energy check.
ENERGY_TOLERANCE_TEMPERATURE = 100.0


class Hamiltonian:
    """The atoms' positions and momenta as exact variables, and their forces.

    Attribute ``layout``: the rigid bodies, None here (see
    :class:`~.rigid.system.RigidSystem`).

    Parameters
    ----------
    atoms : ase.Atoms
        Shows the exact values: positions after every drift, momenta when
        shown (after every step observers see, at the end of a run, before
        an energy check).
    grid : Grid
        The two quanta.
    counts : dict
        int64 ``[n_atoms, 3]`` counts for ``'position'`` and ``'momentum'``.
    masses_n : numpy.ndarray ``[n_atoms]``
        amu.
    project : callable
        In-place constraint projection of an ``[n_atoms, 3]`` array.
    purity : force provider
        From :func:`ase_reversible.purity.force_provider`.
    """

    layout = None

    def __init__(self, atoms, grid, counts, masses_n, project, purity):
        self.atoms = atoms
        self.grid = grid
        self.x = ExactVariable('position', counts['position'],
                               grid.position_quantum)
        self.p = ExactVariable('momentum', counts['momentum'],
                               grid.momentum_quantum)
        self.variables = {'position': self.x, 'momentum': self.p}
        self.set_dynamics(masses_n, project, purity)
        self.drift = Drift(self)
        self.kick = Kick(self)

    def set_dynamics(self, masses_n, project, purity):
        """New masses, constraints or force provider (re-prepare the plan)."""
        self.m_n1 = masses_n[:, None]
        # Flat, for the kinetic energy: p / sqrt(m) squared and summed,
        # from the counts with the power-of-two quantum folded in (bitwise
        # the image's products, without the pass that makes the image).
        self._root_inverse_mass_k = np.repeat(1.0 / np.sqrt(masses_n),
                                              3) * self.p.quantum
        self._v_k = np.empty(3 * len(masses_n))
        self.project = project
        #: The FixCom balance of the rounded increments, or None.
        self.centre = getattr(project, 'centre', None)
        self.purity = purity

    @property
    def atom_masses_n1(self):
        """``[n_atoms, 1]`` amu: the atoms' masses (ASE's ``dyn.masses``)."""
        return self.m_n1

    def shown_positions(self):
        """The positions the atoms show of the exact state, ``[n_atoms,
        3]`` (not to be modified)."""
        return self.x.floats

    def thermal_parts(self):
        """What a thermostat acts on besides the momenta:
        ``((variable, masses_k), ...)`` of further momentum-like exact
        variables, each with its mass per coordinate (flat; 0 where the
        coordinate has no motion): none here."""
        return ()

    def encode(self, atoms, project):
        """The counts of the variables the atoms show, by name, on this
        system's grid (``project``: the constraint projection)."""
        return encoded(atoms, self.x.quantum, self.p.quantum, project)

    def show_positions(self):
        """Write the exact positions into the atoms' own array."""
        self.x.write_floats(self.atoms.arrays['positions'])

    def show_momenta(self):
        """Write the momenta the atoms show (:meth:`shown_momenta`) into
        them (creating the array)."""
        momenta = self.atoms.arrays.get('momenta')
        if momenta is None:
            self.atoms.set_momenta(self.shown_momenta(),
                                   apply_constraint=False)
        elif type(self).shown_momenta is Hamiltonian.shown_momenta:
            self.p.write_floats(momenta)  # the counts' image: one pass
        else:
            np.copyto(momenta, self.shown_momenta())

    def shown_momenta(self):
        """The momenta the atoms show, ``[n_atoms, 3]`` (not to be
        modified): the exact image of the momentum counts."""
        return self.p.floats

    def divided_momenta(self, divisor):
        """``p / v``, ``[n_atoms, 3]``, for the exact scalar variable
        ``divisor`` (Nosé's ``s``, the barostat's ``lambda``): computed
        once per value of both, into ``self._shown_nc``."""
        key = (self.p.label, divisor.label)
        if self._shown_key != key:
            np.divide(self.p.floats, float(divisor.floats[0]),
                      out=self._shown_nc)
            self._shown_key = key
        return self._shown_nc

    def show(self):
        """Write positions and momenta."""
        self.show_positions()
        self.show_momenta()

    def momentum_square(self):
        """``sum p^2 / m`` (eV) of the momentum counts' exact image, in
        the same bits on every CPU (Nosé's thermostat is kicked by it)."""
        v_k = np.multiply(self.p.counts.reshape(-1),
                          self._root_inverse_mass_k, out=self._v_k)
        np.multiply(v_k, v_k, out=v_k)
        return float(np.sum(v_k))

    def kinetic_energy(self):
        """``sum p^2 / 2m`` (eV) of the exact momenta: the energy check's
        trigger, three numpy calls and no force call."""
        return 0.5 * self.momentum_square()

    def energy(self):
        """``(total energy, proposed tolerance)`` in eV, for the check: the
        tolerance is the kinetic energy or that of the atoms at
        ``ENERGY_TOLERANCE_TEMPERATURE``, whichever is larger."""
        self.show_momenta()  # a run nobody watches shows them only at its end
        kinetic = self.atoms.get_kinetic_energy()
        energy = self.atoms.get_potential_energy() + kinetic
        floor = 1.5 * len(self.atoms) * units.kB * \
            ENERGY_TOLERANCE_TEMPERATURE
        return energy, max(kinetic, floor)


def largest_kick(scheme, composition, dt, kick):
    """ASE time units: the largest ``|c h|`` of the sub-step ``kick`` in a
    step of ``scheme`` composed by ``composition`` at time step ``dt``
    (what the force-purity provider's momentum quantum must allow for)."""
    return abs(dt) * max(abs(c) for kind, c in compose(scheme, composition)
                         if kind == kick)


class Drift(SubStep):
    """``x += round_odd(c h P p / m / q_x)``; shown on the atoms at once.

    Drift-kick-drift ends a step and starts the next with the same drift of
    the same momenta: its rounding is reused, like the kick's.
    """

    def __init__(self, system):
        self.system = system
        self._y_nc = np.empty(system.x.ints.shape)
        # (momenta label, c h) of the increment in _y_nc and its bound.
        # New masses or constraints come with new labels (the state is
        # installed again), so the key needs neither.
        self._y_key = self._y_max = None
        self._moved = None  # (position labels before, after) the last drift

    def prepare(self, ch):
        # Applied to the momentum counts ip with the quantum folded in:
        # ip * (qp * f) is bitwise (ip * qp) * f, qp being a power of two,
        # and needs no pass to make the image ip * qp.  Spread over the
        # three columns: numpy multiplies arrays of one shape several times
        # faster than it broadcasts a column (bitwise the same products).
        s = self.system
        factor_n1 = ch / s.x.quantum / s.m_n1
        # max |y| is bounded by the momenta's bound times this, instead of
        # found by a pass over y: a projection onto a plane or line
        # lengthens no vector, so no component exceeds sqrt(3) times the
        # largest before it; the factor 2 covers that and the rounding of
        # the products, the 1 added in apply the rounding of y.
        return (ch, np.repeat(factor_n1 * s.p.quantum, self._y_nc.shape[1],
                              axis=1),
                2.0 * s.p.quantum * float(np.abs(factor_n1).max(initial=0.0)))

    def apply(self, prepared):
        self._drift(prepared, (self.system.p.label, prepared[0]))

    def _drift(self, prepared, key, scale=None):
        """The drift of ``prepared``, its velocities times the float
        ``scale`` if given; ``key`` names the increment (the values it
        is a function of), so one already computed is reused."""
        ch, factor_nc, growth = prepared
        s = self.system
        y_nc = self._y_nc
        if self._y_key != key:
            self._y_key = None  # y_nc is about to be overwritten
            np.multiply(s.p.counts, factor_nc, out=y_nc)
            if scale is not None:
                y_nc *= scale
                growth *= abs(scale)
            if s.project is not no_projection:
                s.project(y_nc)
            round_odd(y_nc, out=y_nc)
            self._y_max = growth * s.p.bound + 1.0
            if s.centre is not None and s.centre.equal_masses:
                s.centre.balance(y_nc)
                # The balance takes at most max|y| + 1 from an atom.
                self._y_max = 2.0 * self._y_max + 1.0
            self._y_key = key
        before = s.x.label
        s.x.add_integers(y_nc, self._y_max)
        self._moved = (before, s.x.label)
        s.show_positions()

    def last_move(self):
        """``(c h, positions label before)`` of the drift that brought the
        positions where they are, with the present momenta; None if the
        positions or momenta changed since."""
        s, moved, key = self.system, self._moved, self._y_key
        if moved is None or key is None or moved[1] != s.x.label \
                or key[0] != s.p.label:
            return None
        return key[-1], moved[0]

    def rollback(self):
        self._y_key = None  # y_nc may hold a failed step's drift
        self.system.show_positions()

    def adjoint(self, cotangents, ch):
        """``a_p += c h P a_x / m``, after the pending kicks."""
        cotangents.flush()
        w_nc = np.divide(cotangents['position'], self.system.m_n1)
        self.system.project(w_nc)
        w_nc *= ch
        cotangents['momentum'] += w_nc


class Kick(SubStep):
    """``p += round_odd(c h P F(x) / q_p)``, the forces made pure.

    Forces are computed once per position value; kick-drift-kick ends a
    step and starts the next with the same kick at the same positions, so
    its rounding is reused, not recomputed.
    """

    def __init__(self, system):
        self.system = system
        shape = system.x.ints.shape
        self._y_nc = np.empty(shape)
        self._r_nc = np.empty(shape)
        self.forget()

    def forget(self):
        """Drop cached forces (a new calculator, even an equal one)."""
        self._r_key = self._r_max = None
        self._f_cache = None
        self._saved = None

    def prepare(self, ch):
        return ch / self.system.p.quantum

    def forces(self):
        """Forces ``[n_atoms, 3]`` (eV/Å) at the current grid positions."""
        s = self.system
        if self._f_cache is not None and self._f_cache[0] == s.x.label:
            return self._f_cache[1]
        f_nc = s.purity.forces(s.atoms)
        self._f_cache = (s.x.label, f_nc)
        return f_nc

    def held(self, label=None):
        """``(forces, kick)``: what the steps so far left for the present
        positions (or those of position ``label``), computing nothing.
        ``forces`` ``[n_atoms, 3]`` (eV/Å) are those the kicks use (or
        None); ``kick`` is ``(scale, increments)`` of the last rounded kick
        there (or None)."""
        if label is None:
            label = self.system.x.label
        f = self._f_cache
        r = self._r_key
        return (f[1] if f is not None and f[0] == label else None,
                (r[1], self._r_nc) if r is not None and r[0] == label
                else None)

    def apply(self, scale):
        s = self.system
        r_nc = self._r_nc
        key = (s.x.label, scale)
        if self._r_key != key:
            self._r_key = self._r_max = None  # r_nc is about to be overwritten
            f_used_nc = s.purity.rounded_kick(
                s.atoms, self.forces(), scale, s.project, out=r_nc,
                scratch=self._y_nc)
            if s.centre is not None:
                s.centre.balance(r_nc)
            self._f_cache = (s.x.label, f_used_nc)
            self._r_key = key
        try:
            # The range of r_nc is checked once, the first time it is added.
            self._r_max = s.p.add_integers(r_nc, self._r_max)
        except QuantumRangeError:
            if not np.all(np.isfinite(self._f_cache[1])):
                raise non_finite_forces(s.atoms.calc) from None
            raise

    def checkpoint(self):
        self._saved = self._f_cache

    def rollback(self):
        self._f_cache = self._saved
        self._r_key = self._r_max = None  # r_nc may hold a failed step's kick

    def adjoint(self, cotangents, ch):
        # Deferred: the next drift or the end applies it, merged with any
        # other kick at these positions.
        cotangents.defer(self._pull_back, ch)

    def _pull_back(self, cotangents, ch):
        """``a_x += c h (dF/dx)^T P a_p`` and ``a_theta += c h (dF/dtheta)^T
        P a_p`` at the atoms' current positions: one product."""
        s = self.system
        w_nc = np.array(cotangents['momentum'])
        if s.centre is not None:
            s.centre.pull_back(w_nc)
        s.project(w_nc)
        if not w_nc.any():
            return  # J^T 0 = 0 (a loss on positions only starts this way)
        dx_nc, dtheta = cotangents.product(s.atoms, w_nc)
        if dx_nc.shape != w_nc.shape:
            raise ValueError(f'The product for the positions has shape '
                             f'{dx_nc.shape}, expected {w_nc.shape}')
        cotangents.products += 1
        cotangents['position'] += ch * dx_nc
        # Forces a constraint adds (Hookean's), which the calculator's
        # product does not see.
        added_nc = added_force_product(s.atoms, w_nc)
        if added_nc is not None:
            cotangents['position'] += ch * added_nc
        grads = cotangents.grad_parameters
        for name in grads:
            grads[name] = grads[name] + ch * np.asarray(dtheta[name],
                                                        dtype=float)


def non_finite_forces(calc):
    """The error of a kick whose forces (from ``calc``) are not finite."""
    return NonFiniteForcesError(
        f'{type(calc).__name__} returned non-finite forces; the step was '
        'not taken and the state is still reversible. Check the structure '
        '(overlapping atoms?) and the calculator.')


def explain_energy_drift(number, drift, tolerance, dt):
    """The message of the energy check that stopped a run at step
    ``number`` (energies in eV, ``dt`` in ASE time units)."""
    return (
        f'The total energy has changed by {drift:.4g} eV since the '
        f'anchor of reversal (tolerance {tolerance:.4g} eV) '
        f'after step {number}: the integration is unstable. Use '
        f'a smaller time step (now {abs(dt) / units.fs:g} fs). '
        'The step was not taken; the state is valid and reverse() '
        'leads back exactly (the check stays quiet until the energy '
        'is within the tolerance again). If the change is expected, '
        'raise energy_tolerance or pass energy_check=0.')
