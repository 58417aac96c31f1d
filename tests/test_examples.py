"""The examples run: each in its quick mode, saving its picture.

Their full runs (under a minute each) made the pictures in docs/images; the
quick modes check here that the scripts still work end to end, that the
optimisation they show makes progress, and that every gradient evaluation
left the atoms back at their start bit for bit.
"""

import importlib.util
import sys
from pathlib import Path

import pytest

EXAMPLES = Path(__file__).resolve().parent.parent / 'examples'


def load(name):
    spec = importlib.util.spec_from_file_location(name,
                                                  EXAMPLES / f'{name}.py')
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module  # dataclasses look their module up there
    spec.loader.exec_module(module)
    return module


@pytest.mark.parametrize('name', ['steer_argon', 'keyframe_chain'])
def test_example_quick_mode(name, tmp_path):
    result = load(name).main(out_dir=tmp_path, quick=True)
    picture = Path(result['picture'])
    assert picture.parent == tmp_path
    assert picture.exists() and picture.stat().st_size > 10_000
    assert result['exact_return'] is True
    assert result['iterations'] >= 1
    # The quick modes stop early, but the loss must fall a long way.
    assert result['loss_final'] < 0.1 * result['loss_initial']
