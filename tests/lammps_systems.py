"""The LAMMPS systems of the LAMMPS tests, as input lines.

One fcc crystal builder for every material the LAMMPS tests and their
workers run, so that "argon at 240 K" is the same input everywhere.
"""

#: name -> (units, fcc lattice parameter, atom types, the lines after
#: ``create_atoms``: types, masses and the pair potential).  ``{potential}``
#: stands for the EAM file's path.
MATERIALS = {
    'argon': ('metal', '5.26', 1, ['mass 1 39.948', 'pair_style lj/cut 8.5',
                                   'pair_coeff 1 1 0.0104 3.40']),
    'copper': ('metal', '3.615', 1, ['mass 1 63.546', 'pair_style eam',
                                     'pair_coeff * * {potential}']),
    'lj': ('lj', '0.8442', 1, ['mass 1 1.0', 'pair_style lj/cut 2.5',
                               'pair_coeff 1 1 1.0 1.0']),
    'lj-binary': ('lj', '0.8442', 2, [
        'set type 1 type/fraction 2 0.2 12393', 'mass 1 1.0', 'mass 2 2.0',
        'pair_style lj/cut 2.5', 'pair_coeff 1 1 1.0 1.0',
        'pair_coeff 2 2 1.0 0.9', 'pair_coeff 1 2 1.2 0.95']),
}


def fcc_box(material, cells, temperature, seed, mom=False):
    """Input lines: ``material``'s fcc crystal filling a periodic box of
    ``cells`` lattice cells a side, with velocities drawn at
    ``temperature`` (the units' temperature) from ``seed``, the total
    momentum zeroed if ``mom``."""
    units, lattice, types, rest = MATERIALS[material]
    return '\n'.join([
        f'units {units}', 'boundary p p p', f'lattice fcc {lattice}',
        f'region box block 0 {cells} 0 {cells} 0 {cells}',
        f'create_box {types} box', 'create_atoms 1 box', *rest,
        f'velocity all create {temperature} {seed} loop geom'
        + (' mom yes' if mom else '')])


def start(lammps, script, timestep, restart=None, data=None):
    """A new, quiet LAMMPS instance (of the ``lammps`` module) holding
    ``script``'s system, or the one of a ``restart`` or ``data`` file with
    ``script``'s masses and pair potential given again; its time step
    ``timestep``."""
    lmp = lammps.lammps(cmdargs=['-log', 'none', '-screen', 'none'])
    lines = script.splitlines()
    if restart or data:
        lmp.command(lines[0])  # the units
        if data:  # a data file's Pair Coeffs need the style first
            lmp.command(next(line for line in lines
                             if line.startswith('pair_style')))
        lmp.command(f'read_restart {restart}' if restart
                    else f'read_data {data}')
        lines = [line for line in lines
                 if line.split()[0] in ('mass', 'pair_style', 'pair_coeff')]
    for line in lines:
        lmp.command(line)
    lmp.command(f'timestep {timestep!r}')
    return lmp
