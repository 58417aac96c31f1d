"""The whole cell's barostat with Nosé's thermostat: ``ReversibleNPT(...,
thermostat='nose')``, as :mod:`~ase_reversible.md.npt.nose` is for the isotropic one (the
derivation is in docs/pressure.md, "Nosé's thermostat on the barostat";
here the piston has six entries, so ``g = N_f + 7``)."""

from __future__ import annotations

import math

from ...core.codec import encode, round_odd
from ...core.portable import dot, rows_times_matrix
from ..nose.system import PI_KICK, TICK, NoseChain, ThermostatDrift, Tick, link
from .cell import (CellDrift, CellHamiltonian, CellKinetic, CellPiston,
                   CellVirial, ReversibleNPT)
from .nose import (PI_PISTON, AtomsThermostatKick, PistonThermostatKick,
                   ReversibleIsotropicNoseNPT)
from .system import DRIFT, KINETIC, PISTON, VIRIAL

#: The piston's entries, each thermostatted with the atoms.
CELL_ENTRIES = 6


class CellNoseHamiltonian(NoseChain, CellHamiltonian):
    """:class:`~.cell.CellHamiltonian` whose ``'momentum'`` holds ``pi' =
    s pi`` and whose piston momenta hold ``P' = s P``, with Nosé's chain;
    the atoms show ``p = pi' M^-T / s``."""

    dynamics_name = 'ReversibleNPT'

    def __init__(self, atoms, grid, counts, masses_n, project, purity):
        self.s = None
        self.tchain = 1
        super().__init__(atoms, grid, counts, masses_n, project, purity)
        self.drift = CellNoseDrift(self)

    def count(self, degrees_of_freedom):
        """Thermostat ``degrees_of_freedom`` (``N_f``): ``g = N_f + 7``,
        the atoms' momenta, the piston's six and Nosé's ``s``."""
        self.degrees_of_freedom = degrees_of_freedom
        self.g = degrees_of_freedom + CELL_ENTRIES + 1

    def _s(self):
        return 1.0 if self.s is None else self.s_value()

    def _labels(self):
        return (self.p.label, self.lam.label,
                None if self.s is None else self.s.label)

    def shown_momenta(self):
        key = self._labels()
        if self._shown_key != key:
            self._shown_nc[:] = rows_times_matrix(
                self.p.floats, self.matrices()[1].T)
            self._shown_nc /= self._s()
            self._shown_key = key
        return self._shown_nc

    def counts_of(self, positions_nc, momenta_nc):
        """``(rho, pi')`` counts of shown positions and momenta at the
        present ``M`` and ``s``."""
        m, inverse = self.matrices()
        return (encode(rows_times_matrix(positions_nc, inverse),
                       self.x.quantum, 'position'),
                encode(rows_times_matrix(momenta_nc, m.T) * self._s(),
                       self.p.quantum, 'momentum'))

    def velocities(self):
        """``(p, p M^-1 / m)`` of the real momenta (cached per value of
        ``pi'``, ``M`` and ``s``)."""
        key = self._labels()
        if self._velocities is None or self._velocities[0] != key:
            p_nc = self.shown_momenta()
            self._velocities = (key, p_nc, rows_times_matrix(
                p_nc, self.matrices()[1]) / self.m_n1)
        return self._velocities[1], self._velocities[2]

    def piston_momentum(self):
        """The real ``P = P' / s`` (six, eV ASE time)."""
        return self.p_lam.floats / self.s_value()

    def barostat_energy(self) -> float:
        """``P V + |P'|**2 / (2 W s**2) + kT (ln M11 + 2 ln M22)``, eV."""
        m = self.matrices()[0]
        p = self.piston_momentum()
        return (self.pressure * self.volume() + 0.5 * dot(p, p) / self.W
                + self.kT * (math.log(m[1, 1]) + 2.0 * math.log(m[2, 2])))


class CellNoseDrift(CellDrift):
    """``rho += round_odd(c h pi' G^-1 / (m s**2) / q_x)``: the real
    velocities ``p M^-1 / m`` over ``s``."""

    def apply(self, prepared):
        ch = prepared[0]
        s = self.system
        y_nc = s.velocities()[1] * (ch / (s.x.quantum * s.s_value()))
        round_odd(y_nc, out=y_nc)
        s.x.add_integers(y_nc)
        self._moved = None


class CellNoseKinetic(CellKinetic):
    """``P' += round_odd(c h sum q^T p / m / q)`` of the real momenta
    (``p = pi' M^-T / s``, ``q = p M^-1``): the virtual kinetic energy's
    derivative in ``M`` at fixed ``pi'`` and ``s``."""

    def apply(self, scale):
        s = self.system
        key = s._labels()
        if self._key != key:
            self._force = self.force()
            self._key = key
        s.p_lam.add_rounded(scale * self._force)


class CellNosePiston(CellPiston):
    """``M += round_odd(c h P' / (W s**2) / q)``."""

    def momentum(self):
        """``P' / s**2`` (six), eV ASE time."""
        s = self.system.s_value()
        return self.system.p_lam.floats / (s * s)


class CellAtomsThermostatKick(AtomsThermostatKick):
    """``pi_1 += round_odd(c h (2K - g kT) / s / q)``, ``K`` the atoms'
    real kinetic energy."""

    def force(self):
        """eV: ``(2K - g kT) / s``."""
        sys = self.system
        return (2.0 * sys.kinetic_energy() - sys.g * sys.kT) / sys.s_value()


class CellPistonThermostatKick(PistonThermostatKick):
    """``pi_1 += round_odd(c h |P'|**2 / (W s**3) / q)``."""

    def force(self):
        """eV: ``|P'|**2 / (W s**3)``."""
        sys = self.system
        p, s = sys.p_lam.floats, sys.s_value()
        return dot(p, p) / (sys.W * (s * s * s))


class ReversibleNoseNPT(ReversibleIsotropicNoseNPT, ReversibleNPT):
    """:class:`~.cell.ReversibleNPT` with Nosé's thermostat: what
    ``ReversibleNPT(..., thermostat='nose')`` constructs, the
    deterministic counterpart of ASE's ``MTKNPT``.  Arguments, refusals,
    restarts and views as for
    :class:`~.nose.ReversibleIsotropicNoseNPT`; the cell as for
    :class:`~.cell.ReversibleNPT` (``barostat_momentum``: the six real
    momenta ``P' / s``).  ``N_f`` as there, ``g = N_f + 7``.
    :meth:`backpropagate` is refused (its adjoints are not written);
    :meth:`write_buffer` too.
    """

    _system_class = CellNoseHamiltonian

    @staticmethod
    def _nose_substeps(system):
        substeps = {VIRIAL: CellVirial(system), DRIFT: system.drift,
                    KINETIC: CellNoseKinetic(system),
                    PISTON: CellNosePiston(system),
                    PI_KICK: CellAtomsThermostatKick(system),
                    PI_PISTON: CellPistonThermostatKick(system),
                    TICK: Tick(system)}
        for j in range(1, system.tchain + 1):
            substeps[link(j)] = ThermostatDrift(system, j)
        return substeps

    def backpropagate(self, *args, **kwargs):
        """Refused: the adjoints of the whole cell's Nosé sub-steps are
        not written."""
        raise NotImplementedError(
            "ReversibleNPT with thermostat='nose' gives no gradients yet "
            "(its adjoints are not written). Use thermostat='langevin' (the "
            "default) for backpropagate, or ReversibleIsotropicNPT with "
            "thermostat='nose'.")
