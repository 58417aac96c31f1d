"""Who runs the step: the compiled ``fix reversible/nve`` or the Python
path's three LAMMPS fixes, chosen when a
:class:`~.integrator.ReversibleLammps` is made and switchable between
runs; the fixes each path defines for a run and takes away after it."""

from __future__ import annotations

from enum import Enum


class StepPath(str, Enum):
    """Who may run the step (``ReversibleLammps(path=...)``); each is equal
    to its string, which users pass."""

    AUTO = 'auto'
    COMPILED = 'compiled'
    PYTHON = 'python'

    def __str__(self):
        return self.value

    __format__ = str.__format__

    @classmethod
    def of(cls, path):
        """``path`` (a string or a member) as a member, else ValueError."""
        try:
            return cls(path)
        except ValueError:
            raise ValueError(f'path must be one of '
                             f'{", ".join(p.value for p in cls)}, got '
                             f'{path!r}') from None



class StepFixes:
    """The paths of :class:`~.integrator.ReversibleLammps` (a part of it:
    it reads the run's grid, scales and guard settings from there)."""

    def _define_fixes(self):
        n = self.name
        for command in (f'variable {n}_vx atom vx+d2_{n}_k[1]',
                        f'variable {n}_vy atom vy+d2_{n}_k[2]',
                        f'variable {n}_vz atom vz+d2_{n}_k[3]',
                        f'variable {n}_halt equal f_{n}_ext[1]'):
            self.lmp.command(command)
        self._set_sort()

    def _attach(self):
        """Define the fixes of a run, last, so that fixes which change
        forces run before the kick.  They exist only during run(): LAMMPS
        refuses a new timestep while a fix move exists, a run or
        minimisation outside run() must not call the kick, and restart
        and data files written between runs hold nothing of them (the
        pending half-kick is recomputed when a run starts)."""
        n = self.name
        if self.path == StepPath.COMPILED:
            self.lmp.command(compiled_kick_fix(n))
            self.lmp.command(f'fix {n}_nve all reversible/nve '
                             + self._compiled_arguments())
            return
        vz = f'v_{n}_vz' if self.dimension == 3 else 'NULL'  # z stays 0
        for command in (f'fix {n}_k all property/atom d2_{n}_k 3 ghost no',
                        f'fix {n}_move all move variable NULL NULL NULL '
                        f'v_{n}_vx v_{n}_vy {vz}',
                        f'fix {n}_ext all external pf/callback 1 1',
                        f'fix {n}_halt all halt 1 v_{n}_halt > 0.5 '
                        'error continue message no'):
            self.lmp.command(command)
        self.lmp.fix_external_set_vector_length(f'{n}_ext', 1)
        self.lmp.set_fix_external_callback(f'{n}_ext', self._callback, None)

    def _detach(self):
        fixes = (('nve', 'k') if self.path == StepPath.COMPILED else
                 ('halt', 'ext', 'move', 'k'))
        for fix in fixes:
            self.lmp.command(f'unfix {self.name}_{fix}')

    def _compiled_arguments(self):
        """``fix reversible/nve``'s words: the run's grid, guard and
        per-type scales, each float as its exact repr (the fix reads it
        back to the same bits).  Before the grid is chosen (the halted
        setup that measures the starting forces) they are placeholders."""
        ntypes = self.lmp.extract_global('ntypes')
        if self._prepared:
            scales = (self._type_scale[1:] if self._type_scale is not None
                      else [self._scalar_scale] * ntypes)
            words = {'velocity_quantum': self.velocity_quantum,
                     'force_noise': self.force_noise,
                     'extent_factor': self._extent_factor,
                     'sort_bin': self.sort_bin}
        else:
            scales = [0.0] * ntypes
            words = {'velocity_quantum': 1.0, 'force_noise': 0.0,
                     'extent_factor': 1.0, 'sort_bin': self.sort_bin}
        return ' '.join([compiled_kick_words(self.name),
                         *(f'{key} {float(value)!r}'
                           for key, value in words.items()),
                         f'mode {self._mode}', 'scale',
                         *(repr(float(s)) for s in scales)])

    @property
    def path(self):
        """Who runs the step: ``StepPath.COMPILED`` or ``StepPath.PYTHON``,
        equal to the strings ``'compiled'`` and ``'python'``.  Set it
        between runs, on every rank (collective), to continue on the other
        path; ``'auto'`` and ``'compiled'`` load the plugin first, as the
        constructor does."""
        return self._path

    @path.setter
    def path(self, wanted):
        self._path = self._choose_path(wanted)

    def _choose_path(self, wanted):
        """'compiled' if the plugin loads on every rank (and python was not
        asked for), else 'python'; raises where 'compiled' was asked for
        and cannot be had."""
        wanted = StepPath.of(wanted)
        if wanted == StepPath.PYTHON:
            return StepPath.PYTHON
        reason = self._load_plugin_everywhere()
        if not reason:
            return StepPath.COMPILED
        if wanted == StepPath.COMPILED:
            raise RuntimeError(f'the compiled exact step is not available: '
                               f'{reason}. To run on the Python path, '
                               + self.hint('path', 'python'))
        self._print(f'exact runs take the Python path (about 1.1-2x fix '
                    f'nve per step): {_quoted(reason)}')
        return StepPath.PYTHON

    def _load_plugin_everywhere(self):
        """Build and load the plugin on every rank: '' where it loaded on
        all of them, else why not.  Collective: every rank must take the
        same path, so one that failed sends all to Python."""
        from .plugin import PluginUnavailable, load
        reason = ''
        try:
            load(self.lmp)
        except PluginUnavailable as error:
            reason = str(error)
        if self.world.max(1.0 if reason else 0.0)[0] > 0:
            return reason or 'the plugin failed to load on another rank'
        return ''

    def _set_sort(self):
        # The compiled step sorts a setup's atoms itself, finely and then
        # into LAMMPS's own bins (fix_reversible_nve.cpp), which keeps the
        # pair loops' memory locality; the Python path leaves LAMMPS's
        # sort at the fine bins, at up to 4% of fix nve's time per step.
        if self.path == StepPath.PYTHON:
            self.lmp.command(f'atom_modify sort 1000 {self.sort_bin!r}')


def compiled_kick_fix(name):
    """The ``fix property/atom`` of the compiled fixes' kicks: two arrays,
    since a step writes its kicks beside the pending ones (which a step
    that fails leaves as they were) and the fix leaves the pending kick in
    ``d2_{name}_k`` between runs."""
    return (f'fix {name}_k all property/atom d2_{name}_k 3 '
            f'd2_{name}_knext 3 ghost no')


def compiled_kick_words(name):
    """The compiled fixes' arguments naming those arrays."""
    return f'kick {name}_k next {name}_knext'


def _quoted(reason):
    """A reason as one line of LAMMPS's ``print``: no quotes, since print
    ends at a double quote and stops the script with "Unmatched single
    quote" at an apostrophe (LAMMPS 22 Jul 2025)."""
    return ' '.join(reason.replace('"', '`').replace("'", '`').split())
