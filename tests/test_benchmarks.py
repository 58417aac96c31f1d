"""The benchmarks keep working, measurement and rendering apart.

Every section measures in its quick mode into a temporary directory, then
the renderer builds the page and plots from that JSON alone.  Only
behaviour is checked: no timing is asserted here (timings live in
docs/benchmarks.md).
"""

import json
import re
import subprocess
import sys
from pathlib import Path

import pytest

from tiers import SLOW

ROOT = Path(__file__).resolve().parent.parent
#: Every section, as docs/benchmarks.md names them in its generated
#: blocks' markers (read as text: no test loads a module of benchmarks/).
#: That the committed page is what the stored results render to is checked
#: by ``python benchmarks/render.py --check`` (a CI step of its own).
MEASURED = re.compile(r'<!-- (\w+) measured: written by benchmarks/render')
SECTIONS = MEASURED.findall((ROOT / 'docs' / 'benchmarks.md').read_text())


@pytest.fixture(scope='module')
def quick_run(tmp_path_factory):
    # The benchmarks measure asap3 beside ASE's calculators.
    pytest.importorskip('asap3', reason='the benchmarks need asap3')
    out = tmp_path_factory.mktemp('benchmarks')
    measured = subprocess.run(
        [sys.executable, str(ROOT / 'benchmarks' / 'run_all.py'), '--quick',
         '--out', str(out), '--only', *SECTIONS], cwd=ROOT,
        capture_output=True, text=True, timeout=900)
    assert measured.returncode == 0, measured.stderr[-3000:]
    # Rendered again by the renderer alone, from the stored JSON.
    (out / 'benchmarks.md').unlink()
    for png in (out / 'benchmarks').glob('*.png'):
        png.unlink()
    rendered = subprocess.run(
        [sys.executable, str(ROOT / 'benchmarks' / 'render.py'),
         '--out', str(out)], cwd=ROOT, capture_output=True, text=True,
        timeout=300)
    assert rendered.returncode == 0, rendered.stderr[-3000:]
    return out


@SLOW
def test_quick_mode_stores_and_renders_every_section(quick_run):
    page = (quick_run / 'benchmarks.md').read_text()
    assert len(SECTIONS) > 10
    for name in SECTIONS:
        measured = page.split(f'<!-- {name} measured: ')[1].split(
            f'<!-- end of {name} measured -->')[0]
        assert 'quick mode' in measured, name
        stored = json.loads((quick_run / 'benchmarks' / f'{name}.json')
                            .read_text())
        assert stored['quick'] and stored['results']


@SLOW
def test_quick_mode_writes_the_plots_the_page_shows(quick_run):
    page = (quick_run / 'benchmarks.md').read_text()
    images = re.findall(r'!\[[^\]]*\]\(([^)]+)\)', page)
    assert images
    for image in images:
        path = quick_run / image
        assert path.exists() and path.stat().st_size > 1000, image

