"""Exact, reversible constant-temperature runs inside LAMMPS: Nosé's
thermostat as ``fix reversible/nvt``.

The dynamics is that of :mod:`ase_reversible.md.nose` (Nosé's extended
Hamiltonian in virtual time, split into exact shears, step ``B/2 C/2 A C/2
B/2``), run by the compiled fix on every rank's own atoms:

* the exact per-atom variable is the virtual velocity ``v' = s v``, on the
  velocity grid; LAMMPS's ``v`` shows ``v' / s``, so thermo output, dumps
  and restart files see real velocities.  Between runs only ``v`` is kept:
  ``v'`` is recovered from ``(v, s)`` when a run starts, exactly while its
  counts stay below 2^50 (two roundings of 2^-53 each);
* ``s``, ``pi`` and the real-time clock are global, on power-of-two grids
  (``S_QUANTUM``, ``PI_BITS``, ``CLOCK_BITS`` of the ASE thermostat), the
  same bits on every rank;
* the kinetic term ``sum m v'^2`` is an integer sum of squared velocity
  counts, reduced over the ranks in the step's one collective together
  with the guard's verdict, so it has the same bits on any number of ranks
  and in any order of the atoms.

``g = N_f + 1`` with ``N_f = d N - d`` (``d`` the dimension): the total
momentum is conserved, and must be zero for the frames to be canonical
(the run warns otherwise).  ``Q = g kB T tdamp^2``.
"""

from __future__ import annotations

import math
import warnings

import numpy as np

from ..errors import UnstableIntegrationError
from ..md.nose.thermostat import (CENTRE_OF_MASS_TOLERANCE, RECOVERABLE,
                                  S_QUANTUM, clock_quantum,
                                  free_degrees_of_freedom, pi_quantum,
                                  thermostat_mass)
from .fixes import StepPath, compiled_kick_fix, compiled_kick_words
from .integrator import FORCE_NOISE, ReversibleLammps, fix_vector

_S_NOT_POSITIVE = 8  # the fix's verdict: s would have reached zero


class ReversibleLammpsNose(ReversibleLammps):
    """Exact reversible Nosé dynamics (NVT) on a running LAMMPS instance.

    Parameters
    ----------
    lmp : lammps.lammps
        As for :class:`~.integrator.ReversibleLammps`.
    temperature : float
        Target temperature, LAMMPS temperature units (K, or reduced in
        ``lj`` units).
    tdamp : float
        The thermostat's time, LAMMPS time units (ps in ``metal``, fs in
        ``real``, tau in ``lj``; ``100 * timestep`` is a common choice, as
        for ``fix nvt``'s Tdamp): ``Q = g kB T tdamp**2``.
    velocity_quantum, force_noise, sort_bin, name, hint
        As for :class:`~.integrator.ReversibleLammps`; the velocity grid is
        that of the virtual velocities ``v'``.
    path : {'auto', 'compiled'}
        The thermostat exists only as the compiled fix: where the plugin
        cannot be built this raises, saying what to do.

    Steps are equal in Nosé's virtual time: a step of ``dt`` is ``dt / s``
    of real time (:attr:`clock` sums them).  A run with ``-dt`` lands on its
    start bit for bit: positions, ``v'``, ``s``, ``pi`` and the clock.  A
    restart file written between runs holds ``s``, ``pi`` and the clock
    (the fix ``{name}_nvt`` stays defined, inert, between runs); construct
    this object right after ``read_restart`` so that its fix takes them.
    """

    _OWN_FIXES = ReversibleLammps._OWN_FIXES + ('nvt', 'vv')

    def __init__(self, lmp, *, temperature, tdamp, velocity_quantum=None,
                 force_noise=FORCE_NOISE, sort_bin=None, name='rev',
                 path='auto', hint=None):
        self.temperature = _positive(temperature, 'temperature')
        self.tdamp = _positive(tdamp, 'tdamp')
        if path not in (StepPath.AUTO, StepPath.COMPILED):
            raise ValueError(f'the Nosé thermostat runs only on the compiled '
                             f'path (path "auto" or "compiled"), not {path!r}')
        #: Whether the thermostat's state came from a restart file.
        self.restored = False
        self._fix_defined = False
        self._anchor_thermostat = None
        #: Whether ``s``, ``pi`` and the clock were at the anchor, bit for
        #: bit, at the latest :meth:`compare_with_anchor`.
        self.thermostat_at_anchor = None
        self._warned_moving = False
        super().__init__(lmp, velocity_quantum=velocity_quantum,
                         force_noise=force_noise, sort_bin=sort_bin,
                         name=name, path='compiled', hint=hint)
        if self.restored:
            s, pi, clock = self._state
            self._print(f'thermostat from the restart file: s {s!r}, pi '
                        f'{pi!r}, real time {clock!r}')

    # -- set-up -------------------------------------------------------------

    def _check_system(self):
        super()._check_system()
        # Before anything that may re-initialise LAMMPS (a box snapped by
        # change_box): the fix takes a restart file's state only if it is
        # defined before LAMMPS's next init drops it.
        self._load_plugin()
        #: ``N_f``: the momenta's degrees of freedom, less the total.
        self.degrees_of_freedom = free_degrees_of_freedom(
            int(self.lmp.get_natoms()), self.dimension)
        if self.degrees_of_freedom < 1:
            raise ValueError('the Nosé thermostat needs at least two atoms')
        self.g = self.degrees_of_freedom + 1
        self.kT = float(self.lmp.extract_global('boltz')) * self.temperature
        #: Nosé's mass, LAMMPS energy x time^2.
        self.Q = thermostat_mass(self.g, self.kT, self.tdamp)
        self._quanta = [S_QUANTUM, pi_quantum(self.Q, self.kT), None]
        self._state = [1.0, 0.0, 0.0]
        # Defined already by take_restart_state, or now.
        self._fix_defined = bool(self.lmp.has_id('fix', f'{self.name}_nvt'))
        if not self._fix_defined:
            _define_placeholder(self.lmp, self.name)
            self._fix_defined = True
        state = [self._fix_vector(i) for i in (6, 7, 8)]
        quanta = [self._fix_vector(i) for i in (9, 10, 11)]
        if quanta[0] != 0.0:  # set by the restart file, which wins
            self.restored = True
            self._state, self._quanta = state, quanta

    def _load_plugin(self):
        reason = self._load_plugin_everywhere()
        if reason:
            raise RuntimeError(
                'the Nosé thermostat needs the compiled step (fix '
                'reversible/nvt), which is not available here: '
                f'{reason}. '
                'Install a C++ compiler (g++, or set CXX), or build the '
                'plugin ahead of time where one is, into the same cache '
                'directory: python -m ase_reversible lammps build. Nothing '
                'was changed')

    def _choose_path(self, wanted):
        return StepPath.COMPILED  # loaded by _check_system, or refused there

    def _define_fixes(self):
        self._set_sort()

    def _define_nvt(self, placeholder=False):
        n = self.name
        if self._fix_defined:
            self.lmp.command(f'unfix {n}_nvt')
        self.lmp.command(compiled_kick_fix(n))
        self.lmp.command(f'fix {n}_vv all property/atom d2_{n}_vv 3 '
                         'ghost no')
        quanta = self._quanta if self._quanta[2] is not None else [
            0.0, 0.0, 0.0]
        words = self._compiled_arguments() if not placeholder else ' '.join(
            [f'{compiled_kick_words(n)} velocity_quantum 1.0 force_noise 0.0 '
             'mode halted '
             'scale', *['0.0'] * self.lmp.extract_global('ntypes')])
        pq = 1.0 if placeholder else self.position_quantum
        thermostat = ' '.join([
            f'virtual {n}_vv position_quantum {float(pq)!r}',
            'thermostat', *(repr(float(a)) for a in self._state),
            'quanta', *(repr(float(a)) for a in quanta),
            f'kT {self.kT!r} dof {float(self.g)!r} mass {self.Q!r}'])
        self.lmp.command(f'fix {n}_nvt all reversible/nvt {words} '
                         f'{thermostat}')
        self._fix_defined = True

    def _prepare(self):
        super()._prepare()
        if self._quanta[2] is None:
            self._quanta[2] = clock_quantum(self._timestep())
        self._check_thermostat_grid()
        if not self._warned_moving:
            self._warned_moving = True
            self._warn_if_moving()

    def _check_thermostat_grid(self):
        for value, q, what in zip(self._state, self._quanta,
                                  ('s', 'pi', 'clock')):
            if not (math.isfinite(value) and value / q == round(value / q)
                    and abs(value / q) < 2.0**53):
                raise ValueError(
                    f'the thermostat\'s {what} = {value!r} is not on its '
                    f'grid {q!r}: the state is not one this integrator left')

    def _warn_if_moving(self):
        masses = self._type_masses()
        v = self._local('v')
        m = masses[self._local('type') - 1]
        momentum = self.world.sum(*(m @ v), float(m.sum()))
        mvv2e = float(self.lmp.extract_global('mvv2e'))
        drift = 0.5 * mvv2e * float(momentum[:3] @ momentum[:3]) / momentum[3]
        if drift > CENTRE_OF_MASS_TOLERANCE * self.kT:
            text = (f'the atoms move as a whole (centre-of-mass kinetic '
                    f'energy {drift / self.kT:.3g} kT): the thermostat keeps '
                    'the total momentum and thermostats dN - d degrees of '
                    'freedom, so the run is canonical only at zero total '
                    'momentum (velocity all zero linear, or create with '
                    'mom yes)')
            self._print(f'WARNING: {text}')
            warnings.warn(text, UserWarning, stacklevel=4)

    # -- the run's fixes ----------------------------------------------------

    def _attach(self):
        self._state = self._read_state()
        self._define_nvt(placeholder=not self._prepared)
        if self._prepared:  # v' from (v, s): v shows v' / s exactly
            w = self._local(f'd2_{self.name}_vv')
            v = self._local('v')
            w[...] = self._virtual(v)
            if not np.array_equal(w / self._state[0], v):
                raise RuntimeError('internal: v\' / s does not give back v')

    def _detach(self):
        n = self.name
        self._state = self._read_state()
        self.lmp.command(f'fix_modify {n}_nvt mode halted')  # inert
        self.lmp.command(f'unfix {n}_vv')
        self.lmp.command(f'unfix {n}_k')

    def _fix_id(self):
        return f'{self.name}_nvt'

    def _read_state(self):
        return [self._fix_vector(i) for i in (6, 7, 8)]

    def _virtual(self, v):
        """``v'`` on the grid from real velocities ``v`` and ``s``."""
        q = self.velocity_quantum
        counts = np.rint(v * (self._state[0] / q))
        if not np.all(np.abs(counts) < RECOVERABLE):
            raise ValueError(
                f'virtual velocities of {np.abs(counts).max():.3g} quanta: '
                'above 2^50 they cannot be recovered exactly from v and s. '
                'Use a coarser ' + self.hint('velocity_quantum',
                                             q * 2.0**8))
        return counts * q

    def _snapped_velocities(self, v):
        return self._virtual(v) / self._state[0]

    def _take_back(self):
        self.lmp.command(f'fix_modify {self.name}_nvt takeback')

    def _undo_drift(self):
        self.lmp.command(f'fix_modify {self.name}_nvt undo')
        self.lmp.command(f'reset_timestep {self.step - 1}')

    def _halt_error(self):
        if self._flag & _S_NOT_POSITIVE:
            return UnstableIntegrationError(
                f'the Nosé thermostat coordinate s would have reached zero '
                f'at step {self.step + 1}: the thermostat is unstable. Use a '
                f'larger tdamp (now {self.tdamp!r}) or a smaller time step, '
                'and start nearer the target temperature. The step was not '
                f'taken; the atoms are at step {self.step}, where this '
                'exact run can still be reversed')
        return super()._halt_error()

    # -- what it shows --------------------------------------------------------

    @property
    def s(self) -> float:
        """Nosé's ``s``: real time runs at ``1 / s`` of virtual time."""
        return self._read_state()[0]

    @property
    def pi(self) -> float:
        """Nosé's ``pi``, LAMMPS energy x time."""
        return self._read_state()[1]

    @property
    def clock(self) -> float:
        """Real time of the exact runs, LAMMPS time units (``sum dt / s``;
        goes back when run backwards)."""
        return self._read_state()[2]

    @property
    def quanta(self):
        """The quanta of ``s``, ``pi`` and the clock (the clock's is None
        before the first run)."""
        return tuple(self._quanta)

    def kinetic_temperature(self) -> float:
        """The atoms' temperature from their real velocities, over ``N_f``
        degrees of freedom, LAMMPS temperature units.  Collective."""
        masses = self._type_masses()
        v = self._local('v')
        m = masses[self._local('type') - 1]
        two_k = self.world.sum(float(m @ np.square(v).sum(axis=1)))[0]
        return (float(self.lmp.extract_global('mvv2e')) * two_k
                / (self.degrees_of_freedom
                   * float(self.lmp.extract_global('boltz'))))

    def _summary(self):
        s, pi, clock = self._read_state()
        return (f', thermostat s {s:.6g} pi {pi:.4g} T '
                f'{self.kinetic_temperature():.4g} (target '
                f'{self.temperature:g}), real time {clock:.6g}')

    # -- the anchor ---------------------------------------------------------

    def mark_anchor(self):
        """As :meth:`ReversibleLammps.mark_anchor`, and ``s``, ``pi`` and
        the clock beside the atoms.  The anchor's velocities are the real
        ones, ``v' / s``, which with ``s`` give back ``v'`` exactly."""
        super().mark_anchor()
        self._anchor_thermostat = self._read_state()

    def compare_with_anchor(self):
        """``(off, largest_difference)``: ``off`` counts the atoms whose
        positions or velocities differ from the anchor in any bit, plus one
        if ``s``, ``pi`` or the clock does (then ``thermostat_at_anchor``
        is False).
        Collective."""
        off, largest = super().compare_with_anchor()
        self.thermostat_at_anchor = (
            self._read_state() == self._anchor_thermostat)
        return off + (not self.thermostat_at_anchor), largest

    def todict(self) -> dict:
        return {**super().todict(), 'temperature': self.temperature,
                'tdamp': self.tdamp, 's_quantum': self._quanta[0],
                'pi_quantum': self._quanta[1],
                'clock_quantum': self._quanta[2]}


def take_restart_state(lmp, name='rev'):
    """Right after ``read_restart``: define the thermostat's fix (inert)
    so that it takes ``s``, ``pi`` and the clock from the file before
    LAMMPS's next initialisation (any run, ``write_restart``, ...) drops
    them; a :class:`ReversibleLammpsNose` of the same ``name`` constructed
    later starts from them.  Returns whether the file held them (False,
    with nothing defined, where it did not or the plugin is missing).
    Collective."""
    from .plugin import PluginUnavailable, load
    try:
        load(lmp)
    except PluginUnavailable:
        return False
    _define_placeholder(lmp, name)
    if fix_vector(lmp, f'{name}_nvt', 9) != 0.0:
        return True
    lmp.command(f'unfix {name}_nvt')
    return False


def _define_placeholder(lmp, name):
    """``fix {name}_nvt``, halted, with the quanta zero: nonzero after
    the definition only if a restart file's state was taken."""
    n = name
    lmp.command(compiled_kick_fix(n))
    lmp.command(f'fix {n}_vv all property/atom d2_{n}_vv 3 ghost no')
    ntypes = lmp.extract_global('ntypes')
    lmp.command(' '.join([
        f'fix {n}_nvt all reversible/nvt {compiled_kick_words(n)} '
        'velocity_quantum 1.0 '
        'force_noise 0.0 mode halted scale', *['0.0'] * ntypes,
        f'virtual {n}_vv position_quantum 1.0 thermostat 1.0 0.0 0.0 quanta '
        '0.0 0.0 0.0 kT 0.0 dof 1.0 mass 1.0']))
    lmp.command(f'unfix {n}_vv')
    lmp.command(f'unfix {n}_k')


def _positive(value, name):
    value = float(value)
    if not (math.isfinite(value) and value > 0):
        raise ValueError(f'{name} must be positive and finite, got '
                         f'{value!r}')
    return value


__all__ = ['ReversibleLammpsNose', 'take_restart_state']
