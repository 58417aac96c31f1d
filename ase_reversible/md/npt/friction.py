"""The O step of :class:`~.isotropic.ReversibleIsotropicNPT`: Langevin's
exact friction and noise on ``pi`` (mass ``m lambda**2``) and on the
piston's momentum."""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from ...core.infobuffer import InformationBuffer
from ...core.noise import StepNoise
from ...core.portable import dot
from ...errors import RetraceLimitError
from ..buffered import BufferedStep, buffer_arrays, load_buffer_arrays
from ..langevin import Friction, exact_o_step, exact_ratio
from .system import LAMBDA, P_LAMBDA


def past_the_anchor(system):
    """The message of a step back past the anchor of reversal."""
    return (f'{system.dynamics_name} can only retrace steps it has taken: '
            'this one goes back past the anchor of reversal, where friction '
            '(of the atoms or the piston) would have to be undone that was '
            'never applied. The step was not taken; run forward (positive '
            'dt) from here.')


class ScaledFriction(Friction):
    """Langevin's exact O step on ``pi``, whose mass is ``m lambda**2``:
    the noise's spread is ``lambda`` times that for the mass ``m``, and
    the heat it adds is measured with ``1 / (m lambda**2)``.  With a
    :class:`PistonFriction` (``piston``), the same step also applies it
    to ``p_lambda``."""

    def __init__(self, system, settings, step_of, piston=None):
        super().__init__(system, settings, step_of)
        self.piston = piston
        if piston is not None:
            # The piston's deviate comes from the atoms' draw: a draw costs
            # 120 us however few deviates it makes (one deviate, timeit,
            # load 4.5), so a draw of its own would add that to a step.
            self.noise = _MoreNormals(self.noise.size, piston.size)

    def prepare(self, ch):
        return (super().prepare(ch),
                None if self.piston is None else self.piston.prepare(ch))

    def apply(self, prepared):
        atoms_part, piston_part = prepared
        lam = self.system.lam_value()
        try:
            super().apply(atoms_part._replace(
                sigma_k=atoms_part.sigma_k * lam,
                inverse_mass_k=atoms_part.inverse_mass_k / (lam * lam)))
        except RetraceLimitError:
            raise RetraceLimitError(past_the_anchor(self.system)) from None
        if piston_part is not None:
            self.piston.apply(piston_part, self.noise.extra)

    def forget(self):
        super().forget()
        if self.piston is not None:
            self.piston.forget()

    def arrays(self):
        """The buffers that hold digits as a buffer file holds them, by
        array name: the atoms' under ``buffer``, the piston's under
        ``piston``."""
        arrays = buffer_arrays('buffer', self.active_buffers())
        if self.piston is not None:
            arrays.update(buffer_arrays('piston',
                                        self.piston.active_buffers()))
        return arrays

    def load(self, saved):
        """Take the atoms' and the piston's buffers from a buffer file's
        arrays (``saved``, by name)."""
        super().load(saved)
        load_buffer_arrays(
            'piston', {} if self.piston is None else self.piston.buffers,
            saved, lambda n: 'The buffer file was written with another '
            'pdamp or time step: construct with those of the run that '
            'wrote it.')

    def checkpoint(self):
        super().checkpoint()
        if self.piston is not None:
            self.piston.checkpoint()

    def rollback(self):
        super().rollback()
        if self.piston is not None:
            self.piston.rollback()

    def adjoint(self, cotangents, ch):
        """``pi' = c pi + lambda n`` (``n`` the noise for the mass ``m``,
        the same both ways): ``a_lambda += a_pi' . n``, then ``a_pi = c
        a_pi'``; the piston's ``a_p_lambda *= c_piston``."""
        cotangents.flush()
        s = self.system
        atoms_part, piston_part = self.prepare(ch)
        n_k = s.p.quantum * atoms_part.sigma_k * self.noise.normals(
            atoms_part.key, self.step_of())
        n_nc = n_k.reshape(self.shape)
        if atoms_part.zero_sum is not None:
            n_nc = n_nc - atoms_part.zero_sum[0] * n_nc.sum(axis=0)
        cotangents[LAMBDA] += dot(cotangents['momentum'], n_nc)
        cotangents['momentum'] *= exact_ratio(self.settings().friction,
                                              ch)[1]
        if piston_part is not None:
            cotangents[P_LAMBDA] *= exact_ratio(self.piston.friction, ch)[1]


class _MoreNormals(StepNoise):
    """The atoms' ``size`` deviates of a step, drawn together with
    ``more``, kept as :attr:`extra` for the piston."""

    def __init__(self, size, more):
        super().__init__(size + more)
        self.atoms_size = size
        self.extra = None

    def normals(self, key, step):
        z = super().normals(key, step)
        self.extra = z[self.atoms_size:]
        return z[:self.atoms_size]


class PistonPlan(NamedTuple):
    """One O step of the piston at a coefficient ``ch``, as
    :meth:`PistonFriction.prepare` makes it."""

    #: ``ch > 0``.
    forward: bool
    #: The information buffer of the step's friction ratio.
    buffer: InformationBuffer
    #: The noise's spread, in counts of ``p_lambda``.
    sigma: float


class PistonFriction(BufferedStep):
    """The O step on ``p_lambda`` (a Langevin piston): ``p_lambda <- c
    p_lambda + sqrt((1 - c**2) W kT) xi``, exact as the atoms' (the
    friction through an information buffer, the deviates ``xi`` drawn
    with the atoms' by the counter-based generator).

    Parameters
    ----------
    system : NPTHamiltonian
    friction : float
        1 / ASE time unit (``1 / pdamp``).
    size : int
        Entries of ``p_lambda`` (1; 6 for the full cell's momentum).
    """

    def __init__(self, system, friction, size=1):
        super().__init__()
        self.system = system
        self.friction = friction
        self.size = size

    def prepare(self, ch):
        """What :meth:`apply` needs at the coefficient ``ch``."""
        s = self.system
        n, ratio = exact_ratio(self.friction, ch)
        buffer = self.buffers.get(n)
        if buffer is None:
            buffer = self.buffers[n] = InformationBuffer(self.size, n)
        sigma = math.sqrt((1.0 - ratio * ratio) * s.W * s.kT) \
            / s.p_lam.quantum
        return PistonPlan(ch > 0, buffer, sigma)

    def apply(self, prepared, xi_k):
        """One O step of ``p_lambda`` with the standard normal deviates
        ``xi_k`` (one per entry)."""
        forward, buffer, sigma = prepared
        p = self.system.p_lam
        x_k = p.ints.reshape(-1)
        noise_k = np.rint(sigma * xi_k).astype(np.int64)
        new_k = exact_o_step(buffer, x_k, noise_k, forward, None,
                             past_the_anchor(self.system))
        q = p.quantum
        old_k, new_k_q = x_k * q, new_k * q
        self.heat += 0.5 * (dot(new_k_q, new_k_q) - dot(old_k, old_k)) \
            / self.system.W
        p.add_integers((new_k - x_k).astype(np.float64))
