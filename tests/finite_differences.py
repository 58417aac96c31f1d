"""Finite differences, for checking derivatives against energies and forces."""

import numpy as np

from ase_reversible.app.systems import AR_EPSILON, AR_SIGMA


def central_difference(function, x0, direction, h):
    """``(f(x0 + h d) - f(x0 - h d)) / 2h``."""
    return (function(x0 + h * direction) - function(x0 - h * direction)) \
        / (2 * h)


def at_positions(atoms, quantity):
    """``quantity()`` as a function of the positions ``[n_atoms, 3]``."""
    def evaluate(x_nc):
        atoms.positions = x_nc
        return quantity()
    return evaluate


def energy_gradient(atoms, h):
    """dE/dx ``[n_atoms, 3]`` (eV/Å), one coordinate at a time."""
    x0_nc = atoms.get_positions()
    energy = at_positions(atoms, atoms.get_potential_energy)
    grad_nc = np.zeros_like(x0_nc)
    for i in range(len(atoms)):
        for c in range(3):
            unit_nc = np.zeros_like(x0_nc)
            unit_nc[i, c] = 1.0
            grad_nc[i, c] = central_difference(energy, x0_nc, unit_nc, h)
    atoms.positions = x0_nc
    return grad_nc


def hessian_times(atoms, v_nc, h):
    """``H v`` from the forces along ``v_nc`` (constraints not applied)."""
    x0_nc = atoms.get_positions()
    forces = at_positions(
        atoms, lambda: atoms.get_forces(apply_constraint=False))
    hv_nc = -central_difference(forces, x0_nc, v_nc, h)
    atoms.positions = x0_nc
    return hv_nc


def complex_forces(x_nc, epsilon, sigma):
    """Plain Lennard-Jones forces over all pairs, holomorphic in x."""
    d_nnc = x_nc[None, :, :] - x_nc[:, None, :]      # x_j - x_i
    r2_nn = np.einsum('ijc,ijc->ij', d_nnc, d_nnc)
    np.fill_diagonal(r2_nn, 1.0)
    s6_nn = (sigma**2 / r2_nn)**3
    # du/dr / r for u = 4 eps (s^12 - s^6)
    g_nn = 4 * epsilon * (-12 * s6_nn**2 + 6 * s6_nn) / r2_nn
    np.fill_diagonal(g_nn, 0.0)
    return np.einsum('ij,ijc->ic', g_nn, d_nnc)


def argon_lj_forces():
    """Argon's Lennard-Jones parameters as a dict, and plain Lennard-Jones
    forces ``forces(x_nc)`` that read the dict at every call: a complex
    step put into the dict reaches the forces."""
    potential = {'epsilon': AR_EPSILON, 'sigma': AR_SIGMA}

    def forces(x_nc):
        return complex_forces(x_nc, potential['epsilon'],
                              potential['sigma'])
    return potential, forces


def float_kick_drift_run(x_nc, p_nc, m_n1, dt, steps, forces, middle):
    """A plain float (or complex) run of ``steps`` steps of ``dt``: half
    kick, half drift, ``p_nc = middle(k, p_nc)`` at step k, half drift,
    half kick.  Masses ``m_n1`` [n_atoms, 1]; returns (x_nc, p_nc)."""
    for k in range(steps):
        p_nc = p_nc + 0.5 * dt * forces(x_nc)
        x_nc = x_nc + 0.5 * dt * p_nc / m_n1
        p_nc = middle(k, p_nc)
        x_nc = x_nc + 0.5 * dt * p_nc / m_n1
        p_nc = p_nc + 0.5 * dt * forces(x_nc)
    return x_nc, p_nc


def complex_step_errors(loss_imag, x0_nc, p0_nc, g, potential, h=1e-20):
    """Relative errors of backpropagate's gradients ``g`` against
    complex-step differentiation of a plain float run.

    ``loss_imag(x_nc, p_nc)`` runs from that complex start and returns the
    imaginary part of the loss; ``potential`` is the dict of the
    parameters the run's forces read, each stepped by ``1j h`` in turn.
    Two random directions (seed 7) of the start's positions, then of its
    momenta, then each parameter: a list of relative errors.
    """
    rng = np.random.default_rng(7)
    errors = []
    for _ in range(2):
        u_nc = rng.normal(size=x0_nc.shape)
        for dx, dp, ours in ((u_nc, 0, g.positions), (0, u_nc, g.momenta)):
            reference = loss_imag(x0_nc + 1j * h * dx,
                                  p0_nc + 1j * h * dp) / h
            errors.append(abs(np.vdot(ours, u_nc) - reference)
                          / abs(reference))
    for name, value in list(potential.items()):
        potential[name] = value + 1j * h
        reference = loss_imag(x0_nc, p0_nc) / h
        potential[name] = value
        errors.append(abs(g.parameters[name] - reference) / abs(reference))
    return errors
