"""A LAMMPS input script, run with the exact integrator.

``mpiexec -n 2 python -m ase_reversible.lammps in.argon [-var NAME VALUE ...]``

The script is an ordinary LAMMPS input, read line by line and handed to
LAMMPS, with lines of one more command, ``reversible``:

``reversible nve [velocity_quantum Q] [force_noise F] [sort_bin B] [path P]``
    From here on, ``run N`` is an exact run (no ``fix nve``: this is the
    integrator).  ``path`` is ``auto`` (default: the compiled ``fix
    reversible/nve``, built on first use, where a C++ compiler is found,
    else the Python path, with one line saying so), ``compiled`` or
    ``python``; both take the same steps to the bit.  ``timestep`` (before or after this line) must be a power
    of two in LAMMPS time units when a run starts; a negative one runs
    back.  Fixes, pair styles and solvers that would make the motion depend
    on more than positions are refused here and at every run.
``reversible nvt temp T tdamp D [velocity_quantum Q] [force_noise F] [sort_bin B]``
    The same, at constant temperature: Nosé's thermostat at ``T`` with
    time ``D`` (LAMMPS units, as ``fix nvt``'s Tdamp), run by the compiled
    ``fix reversible/nvt`` (refused where it cannot be built).  Runs back
    to ``s``, ``pi`` and the real-time clock too; a restart file holds
    them (give this line right after ``read_restart``).
``reversible anchor``
    Keep every atom's exact state beside it (no gather), and the
    thermostat's.
``reversible check``
    Compare every atom with the anchor: prints the verdict, and stops the
    script with an error if any bit differs.
``reversible off``
    ``run`` is LAMMPS's own again.

``include`` files are read the same way.  ``jump``, ``label``, ``next``
and ``if`` are refused while exact runs are on, since LAMMPS would run what
they lead to without the integrator.
"""

from __future__ import annotations

import re
import sys
from pathlib import Path

from .integrator import ReversibleLammps
from .nose import ReversibleLammpsNose, take_restart_state
from .mpi import finalize_mpi, import_lammps

USAGE = ('usage: mpiexec -n RANKS python -m ase_reversible.lammps INPUT '
         '[-var NAME VALUE ...] [-log FILE] [-screen FILE]  (or -in INPUT)\n'
         '       python -m ase_reversible.lammps build [--dir DIR]  (the '
         'compiled step, ahead of time)')

#: Commands that hand control flow to LAMMPS's own reader.
_FLOW = ('jump', 'label', 'next', 'if')

_OPTIONS = {'velocity_quantum': float, 'force_noise': float,
            'sort_bin': float, 'path': str}
#: ``reversible nvt``'s: the thermostat's two, and no path (compiled only).
_NVT_OPTIONS = {'temp': float, 'tdamp': float, 'velocity_quantum': float,
                'force_noise': float, 'sort_bin': float}


class ScriptError(Exception):
    """A line of the script this runner cannot take (message says why)."""


class ScriptRunner:
    """Feeds an input script to ``lmp``, taking the ``reversible`` lines
    and, while exact runs are on, ``run`` lines itself."""

    def __init__(self, lmp):
        self.lmp = lmp
        self.exact = None
        self.on = False
        #: The script's variables (name -> expression) and fixes (ID ->
        #: words), as its lines define them: LAMMPS's info does not list a
        #: fix's arguments.
        self.variables = {}
        self.fixes = {}
        #: Whether the script gives ``reversible nvt``: then a restart
        #: file's thermostat is taken as soon as it is read.
        self.expects_nvt = False

    def file(self, path):
        """Run every line of the script at ``path``."""
        path = Path(path)
        self.expects_nvt = self.expects_nvt or any(
            line.split()[:2] == ['reversible', 'nvt']
            for _, line in _lines(path))
        for number, line in _lines(path):
            try:
                self.line(line)
            except ScriptError as error:
                raise ScriptError(f'{path}:{number}: {error}') from None

    def line(self, line):
        """One logical line (continuations joined)."""
        words = line.split('#', 1)[0].split()
        if not words:
            return
        command = words[0]
        if command == 'reversible':
            return self._reversible(words[1:])
        if command == 'include':  # relative to the working directory,
            return self.file(words[1])  # as LAMMPS reads it
        if self.on and command in _FLOW:
            raise ScriptError(
                f'{command} is not supported while exact runs are on: LAMMPS '
                'would run what it leads to without the integrator. Write the '
                'runs out, or drive ReversibleLammps from Python')
        if self.on and command == 'run':
            return self._run(words[1:])
        self.lmp.command(line)
        self._note(command, words[1:])
        if command == 'read_restart' and self.expects_nvt \
                and self.exact is None:
            # Before any later line can initialise LAMMPS, which drops a
            # restart file's fix state unless the fix is defined.
            take_restart_state(self.lmp)

    def _note(self, command, words):
        """Keep the variables and fixes a later run must check."""
        if command == 'variable' and len(words) >= 2:
            self.variables[words[0]] = ' '.join(words[1:])
        elif command == 'fix' and len(words) >= 3:
            self.fixes[words[0]] = words
        elif command == 'unfix' and words:
            self.fixes.pop(words[0], None)

    def _check_step_dependence(self):
        """Refuse a fix whose arguments are variables of the step number:
        LAMMPS's step count rises on the way back too, so its forces on the
        way back would not be those of the way out."""
        for fix, words in self.fixes.items():
            for name in re.findall(r'\bv_(\w+)', ' '.join(words[3:])):
                if self._depends_on_step(name, set()):
                    raise ScriptError(
                        f'fix {fix} ({words[2]}) takes variable {name}, '
                        'which depends on the step number: LAMMPS counts '
                        'steps up on the way back too, so its forces there '
                        'would not be those of the way out. Write it as a '
                        'function of time (it runs back with the time '
                        f'step), or unfix {fix} before the exact runs')

    def _depends_on_step(self, name, seen):
        if name in seen or name not in self.variables:
            return False
        seen.add(name)
        text = self.variables[name]
        if re.search(r'\b(step|elapsed|elaplong)\b', text):
            return True
        return any(self._depends_on_step(other, seen) for other in
                   re.findall(r'(?:\bv_|\$\{?)(\w+)', text))

    def _reversible(self, words):
        if not words:
            raise ScriptError('reversible needs nve, anchor, check or off')
        what, rest = words[0], words[1:]
        if what in ('nve', 'nvt'):
            if self.exact is not None:
                raise ScriptError('reversible nve or nvt was already given; '
                                  'the grid it chose stays for the whole '
                                  'script')
            self._check_step_dependence()
            if what == 'nve':
                self.exact = ReversibleLammps(self.lmp, **_options(rest),
                                              hint=_hint)
            else:
                options = _options(rest, _NVT_OPTIONS, 'nvt')
                missing = {'temp', 'tdamp'} - set(options)
                if missing:
                    raise ScriptError(
                        'reversible nvt needs temp T and tdamp D (LAMMPS '
                        'units, as for fix nvt), e.g. reversible nvt temp '
                        '100 tdamp 0.5')
                options['temperature'] = options.pop('temp')
                self.exact = ReversibleLammpsNose(
                    self.lmp, **options,
                    hint=lambda option, value: _hint(option, value, 'nvt'))
            self.on = True
        elif what in ('anchor', 'check', 'off') and self.exact is None:
            raise ScriptError(f'reversible {what} before reversible nve '
                              'or nvt')
        elif what == 'anchor':
            self.exact.mark_anchor()
        elif what == 'check':
            off, largest = self.exact.compare_with_anchor()
            if off:
                thermostat = ('' if getattr(self.exact, 'thermostat_at_anchor',
                                            True)
                              else ' (counting the thermostat: s, pi or the '
                              'clock differs)')
                raise ScriptError(
                    f'reversible check: {off} atoms differ from the anchor '
                    f'(by up to {largest:.3g}){thermostat}')
            also = (', and the thermostat (s, pi, clock)'
                    if isinstance(self.exact, ReversibleLammpsNose) else '')
            self.exact._print(f'reversible check: all {self.exact.natoms} '
                              f'atoms{also} are at the anchor, bit for bit')
        elif what == 'off':
            self.on = False
        else:
            raise ScriptError(f'unknown reversible command {what!r}: '
                              'nve, nvt, anchor, check or off')

    def _run(self, words):
        if len(words) != 1:
            raise ScriptError(
                'an exact run takes only a step count (run N); its keywords '
                '(upto, start, stop, pre, post, every) are not supported')
        self.lmp.command(f'variable _reversible_steps equal {words[0]}')
        steps = self.lmp.extract_variable('_reversible_steps')
        self.lmp.command('variable _reversible_steps delete')
        if steps != int(steps) or steps < 0:
            raise ScriptError(f'run needs a whole number of steps >= 0, got '
                              f'{steps!r}')
        self._check_step_dependence()
        self.exact.run(int(steps))


def _hint(option, value, command='nve'):
    """An option as this script's own command gives it."""
    shown = value if isinstance(value, str) else repr(value)
    return f'reversible {command} {option} {shown}'


def _options(words, known=_OPTIONS, command='nve'):
    if len(words) % 2:
        raise ScriptError(f'reversible {command} options come in pairs: '
                          + ', '.join(known))
    options = {}
    for key, value in zip(words[::2], words[1::2]):
        if key == 'path' and command == 'nvt':
            raise ScriptError('reversible nvt runs only on the compiled '
                              'step: it takes no path option')
        if key not in known:
            raise ScriptError(f'unknown reversible {command} option '
                              f'{key!r}: ' + ', '.join(known))
        options[key] = _number(value) if known[key] is float else value
    return options


def _number(text):
    """A float, also written as a power of two: ``2^-20``."""
    if '^' in text:
        base, exponent = text.split('^', 1)
        return float(base) ** float(exponent)
    return float(text)


def _lines(path):
    """``(first line number, logical line)``, continuations (``&``) joined."""
    pending, start = '', None
    for number, raw in enumerate(path.read_text().splitlines(), 1):
        start = start or number
        text = raw.rstrip()
        if text.endswith('&'):
            pending += text[:-1] + ' '
            continue
        yield start, pending + text
        pending, start = '', None
    if pending:
        yield start, pending


def main(argv=None, prog='python -m ase_reversible.lammps'):
    """``python -m ase_reversible.lammps INPUT [LAMMPS options]`` (or
    ``-in INPUT`` among them, as for ``lmp``); returns the exit status.
    ``prog``: the command as typed, for the usage line."""
    argv = sys.argv[1:] if argv is None else list(argv)
    usage = USAGE.replace('python -m ase_reversible.lammps', prog)
    if not argv or argv[0] in ('-h', '--help'):
        print(usage)
        print(__doc__.split('\n\n', 2)[2])
        return 0 if argv else 2
    if argv[0] == 'build':  # not an input script: the compiled step
        from .plugin import main as build
        return build(argv[1:])
    path, lammps_args = _input_and_options(argv)
    if path is None:
        print(usage, file=sys.stderr)
        return 2
    if not path.exists():
        print(f'no such input script: {path}', file=sys.stderr)
        return 2
    lammps = import_lammps()
    lmp = lammps.lammps(cmdargs=lammps_args)
    rank = lmp.extract_setting('world_rank')
    try:
        ScriptRunner(lmp).file(path)
    except Exception as error:  # LAMMPS raises plain Exception
        if rank == 0:
            print(f'ERROR: {error}', file=sys.stderr)
        lmp.close()
        return 1
    lmp.close()
    finalize_mpi()
    return 0


def _input_and_options(argv):
    """The input script (first argument, or after ``-in``/``-i``) and the
    options left for LAMMPS."""
    for flag in ('-in', '-i'):
        if flag in argv[:-1]:
            at = argv.index(flag)
            return Path(argv[at + 1]), argv[:at] + argv[at + 2:]
    if argv[0].startswith('-'):
        return None, argv
    return Path(argv[0]), argv[1:]
