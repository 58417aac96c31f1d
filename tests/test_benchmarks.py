"""The benchmarks keep working: their quick mode runs end to end.

Only behaviour is checked -- every section is rendered and its plots are
written; no timing is asserted here (timings live in docs/benchmarks.md).
"""

import json
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / 'benchmarks'))


@pytest.fixture(scope='module')
def quick_run(tmp_path_factory):
    # The benchmarks measure asap3 beside ASE's calculators.
    pytest.importorskip('asap3', reason='the benchmarks need asap3')
    out = tmp_path_factory.mktemp('benchmarks')
    result = subprocess.run(
        [sys.executable, str(ROOT / 'benchmarks' / 'run_all.py'), '--quick',
         '--out', str(out)], cwd=ROOT, capture_output=True, text=True,
        timeout=600)
    assert result.returncode == 0, result.stderr[-3000:]
    return out


def test_quick_mode_renders_every_section(quick_run):
    import run_all
    page = (quick_run / 'benchmarks.md').read_text()
    for name in run_all.SECTIONS:
        module = run_all._load(name)
        assert f'## {module.TITLE}' in page
        stored = json.loads((quick_run / 'benchmarks' / f'{name}.json')
                            .read_text())
        assert stored['quick'] and stored['results']


def test_quick_mode_writes_the_plots_the_page_shows(quick_run):
    page = (quick_run / 'benchmarks.md').read_text()
    images = re.findall(r'!\[[^\]]*\]\(([^)]+)\)', page)
    assert images
    for image in images:
        path = quick_run / image
        assert path.exists() and path.stat().st_size > 1000, image
