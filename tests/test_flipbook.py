"""The flipbook, headless: frames on demand, keys, pictures, command line.

Everything draws with matplotlib's Agg backend; key presses are real
matplotlib KeyEvents sent through a figure's callback registry, as a
window would send them.
"""

import matplotlib
import numpy as np
import pytest
from ase import units
from ase.calculators.lj import LennardJones as AseLennardJones
from ase.io import Trajectory
from ase.md.verlet import VelocityVerlet
from matplotlib.backend_bases import KeyEvent
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from PIL import Image

from ase_reversible import ReversibleVerlet, UnstableIntegrationError
from ase_reversible.calculators import PendulumChain, make_chain
from ase_reversible.app import cli
from ase_reversible.app.flipbook import Flipbook
from ase_reversible.app.scenes import SCENES
from ase_reversible.app.view import AtomsView

from conftest import AR_EPSILON, AR_RC, AR_SIGMA, DT, argon_cluster

matplotlib.use('Agg')

STRIDE = 3


def chain_book(stride=STRIDE, **kwargs):
    atoms = make_chain(5, angle=80.0)
    atoms.calc = PendulumChain()
    dyn = ReversibleVerlet(atoms, 0.01, **kwargs)
    bonds = [(i, i + 1) for i in range(5)]
    return Flipbook(dyn, stride=stride, view=AtomsView('xz', bonds=bonds))


def state(atoms):
    return atoms.get_positions(), atoms.get_momenta()


def same(atoms, reference):
    x_nc, p_nc = reference
    return (np.array_equal(atoms.positions, x_nc)
            and np.array_equal(atoms.get_momenta(), p_nc))


def twin_at(steps):
    """The state ``steps`` steps on, reached by a plain forward run."""
    book = chain_book()
    book.dyn.run(steps)
    return state(book.atoms)


def press(figure, *keys):
    for key in keys:
        figure.canvas.callbacks.process(
            'key_press_event', KeyEvent('key_press_event', figure.canvas, key))


def new_figure():
    figure = Figure()
    FigureCanvasAgg(figure)
    return figure


def pixels(path):
    return np.asarray(Image.open(path).convert('RGB'))


# -- frames on demand ---------------------------------------------------

def test_frames_are_the_forward_run_whatever_the_route():
    book = chain_book()
    start = state(book.atoms)
    book.goto(7)
    assert book.frame == 7 and book.steps == 7 * STRIDE
    book.goto(2)  # backward: retraced exactly
    assert same(book.atoms, twin_at(2 * STRIDE))
    book.forward(3)
    assert book.frame == 5
    assert same(book.atoms, twin_at(5 * STRIDE))
    book.back(5)
    assert book.frame == 0 and same(book.atoms, start)


def test_keys_step_and_rewind():
    book = chain_book()
    start = state(book.atoms)
    figure = new_figure()
    book.connect(figure)
    press(figure, 'right', 'right', 'up')
    assert book.frame == 12
    assert same(book.atoms, twin_at(12 * STRIDE))
    press(figure, 'left', 'x', 'shift')  # unknown keys change nothing
    assert book.frame == 11
    press(figure, 'down', 'down')  # clamped at frame 0 (first=0)
    assert book.frame == 0 and same(book.atoms, start)
    press(figure, 'pageup', 'home')
    assert book.frame == 0 and same(book.atoms, start)
    assert figure.axes[0].get_title().startswith('frame 0')


def test_a_picture_is_the_same_whichever_way_it_was_reached(tmp_path):
    book = chain_book()
    # Without the caption, which says which way the flipbook last moved.
    forward = book.render(6, tmp_path / 'forward.png', title=False)
    book.goto(20)
    backward = book.render(6, tmp_path / 'backward.png', title=False)
    assert np.array_equal(pixels(forward), pixels(backward))
    other = book.render(7, tmp_path / 'other.png', title=False)
    assert not np.array_equal(pixels(forward), pixels(other))


def test_gif_out_and_back(tmp_path):
    book = chain_book()
    start = state(book.atoms)
    frames = [*range(0, 6), *range(4, -1, -1)]
    path = book.save_gif(tmp_path / 'chain.gif', frames, fps=10)
    with Image.open(path) as gif:
        assert gif.n_frames == len(frames)
        gif.seek(0)
        first = np.asarray(gif.convert('RGB'))
        gif.seek(gif.n_frames - 1)
        last = np.asarray(gif.convert('RGB'))
    # The last frame is frame 0 again; only the caption's heading differs.
    assert not np.array_equal(first, last)
    assert same(book.atoms, start)
    with pytest.raises(ValueError, match='empty'):
        book.save_gif(tmp_path / 'none.gif', [])


def test_browsing_calls_no_observers_and_keeps_them(tmp_path):
    book = chain_book()
    calls = []
    book.dyn.attach(lambda: calls.append(book.dyn.nsteps))
    trajectory = Trajectory(tmp_path / 'md.traj', 'w', book.atoms)
    book.dyn.attach(trajectory)
    book.goto(4).goto(1)
    assert calls == []
    book.dyn.run(2)  # a run of its own still calls them
    trajectory.close()
    assert len(calls) == 2
    assert len(Trajectory(tmp_path / 'md.traj')) == 2


# -- bad input and failures -------------------------------------------------

def test_needs_reversible_dynamics():
    atoms = make_chain(3)
    atoms.calc = PendulumChain()
    with pytest.raises(TypeError, match='ReversibleVerlet'):
        Flipbook(VelocityVerlet(atoms, 0.01))


@pytest.mark.parametrize('stride', [0, -2, 1.5, True])
def test_bad_stride(stride):
    atoms = make_chain(3)
    atoms.calc = PendulumChain()
    with pytest.raises(ValueError, match='stride'):
        Flipbook(ReversibleVerlet(atoms, 0.01), stride=stride)


def test_frames_outside_the_book_are_refused_and_change_nothing():
    book = chain_book()
    book.last = 10
    book.goto(4)
    here = state(book.atoms)
    with pytest.raises(ValueError, match='outside'):
        book.goto(-1)
    with pytest.raises(ValueError, match='outside'):
        book.goto(11)
    with pytest.raises(TypeError, match='whole number'):
        book.goto(2.5)
    assert book.frame == 4 and same(book.atoms, here)


def test_a_move_that_fails_stops_at_a_valid_state():
    # A tolerance far below the rounding of the energy trips the energy
    # check at the first comparison, after step 1.
    book = chain_book(energy_tolerance=1e-300)
    start = state(book.atoms)
    with pytest.raises(UnstableIntegrationError):
        book.goto(5)
    assert book.steps == 1 and book.frame == pytest.approx(1 / STRIDE)
    # From between frames the keys still work, and the way back is exact.
    figure = new_figure()
    book.connect(figure)
    press(figure, 'right')
    # The check raises once, then waits for the energy to come back within
    # the tolerance: the move to frame 1 goes through.
    assert book.frame == 1
    assert 'stopped' not in figure.axes[0].get_title()
    book.goto(0)
    assert same(book.atoms, start)


def test_key_errors_are_shown_not_raised():
    book = chain_book(energy_tolerance=1e-300)
    figure = new_figure()
    book.connect(figure)
    press(figure, 'up')
    assert book.steps == 1
    assert 'stopped: UnstableIntegrationError' in figure.axes[0].get_title()


# -- scenes and the command line -------------------------------------------

@pytest.mark.parametrize('name', sorted(SCENES))
def test_scenes_run_out_and_back_exactly(name):
    scene = SCENES[name]()
    dyn = ReversibleVerlet(scene.atoms, scene.timestep)
    book = Flipbook(dyn, stride=scene.stride, view=scene.view)
    start = state(scene.atoms)
    book.goto(3)
    assert not np.array_equal(scene.atoms.positions, start[0])
    book.goto(0)
    assert same(scene.atoms, start)


def test_command_line_png_and_gif(tmp_path, capsys):
    png = tmp_path / 'ring.png'
    assert cli.flipbook(['ring', '--png', '2', '--out', str(png)]) == 0
    assert pixels(png).shape[2] == 3
    gif = tmp_path / 'chain.gif'
    assert cli.flipbook(['chain', '--gif', '3', '--out', str(gif)]) == 0
    with Image.open(gif) as image:
        assert image.n_frames == 7
    assert 'back at frame 0 after 3 frames each way: True' in \
        capsys.readouterr().out


def test_command_line_from_a_trajectory(tmp_path):
    atoms = argon_cluster(2, 60.0)
    atoms.calc = AseLennardJones(sigma=AR_SIGMA, epsilon=AR_EPSILON,
                                 rc=AR_RC)
    path = tmp_path / 'md.traj'
    ReversibleVerlet(atoms, DT, trajectory=str(path)).run(4)
    png = tmp_path / 'frame.png'
    assert cli.flipbook([str(path), '--index', '2', '--calculator',
                         'lj-argon', '--png', '3', '--out', str(png)]) == 0
    assert png.exists()


def test_a_flipbook_on_a_trajectory_frame_shows_the_frames_own_time(
        tmp_path, monkeypatch):
    atoms = argon_cluster(2, 60.0)
    atoms.calc = AseLennardJones(sigma=AR_SIGMA, epsilon=AR_EPSILON,
                                 rc=AR_RC)
    path = tmp_path / 'md.traj'
    run = ReversibleVerlet(atoms, DT, trajectory=str(path))
    written = []  # the run's clock at each frame, in the order written
    run.attach(lambda: written.append(run.get_time()))
    run.run(4)
    assert written[2] > 0

    # What the command line does with --index 2: the clock goes on from
    # the frame's restart record, and every picture's title shows it.
    captions = []

    class Recording(Flipbook):
        def draw(self, ax=None, title=True):
            captions.append((self.frame, self.time, self.caption()))
            return super().draw(ax, title)
    monkeypatch.setattr(cli, 'Flipbook', Recording)
    assert cli.flipbook([str(path), '--index', '2', '--calculator',
                         'lj-argon', '--gif', '2', '--out',
                         str(tmp_path / 'frames.gif')]) == 0
    seen = {frame: (time, caption) for frame, time, caption in captions}
    assert sorted(seen) == [0, 1, 2]
    for frame, (time, caption) in seen.items():
        expected = written[2] + frame * DT
        assert time == pytest.approx(expected, rel=1e-12)
        assert f't = {expected / units.fs:.6g} fs' in caption
    assert seen[0][0] == written[2]  # frame 0 is the frame's own time


def books_made(monkeypatch):
    """The list the command line's flipbooks are appended to as made."""
    books = []
    monkeypatch.setattr(cli, 'Flipbook',
                        lambda dyn, **kw: books.append(Flipbook(dyn, **kw))
                        or books[-1])
    return books


def test_a_flipbook_on_a_trajectory_frame_retraces_the_files_frames(
        tmp_path, monkeypatch, capsys):
    # Another time step, order and stride than the command line's defaults
    # (5 fs, order 2, 1): they come from the trajectory's header.  The
    # calculator is the one --calculator lj-argon attaches.
    from ase_reversible import LennardJones
    atoms = argon_cluster(2, 60.0)
    atoms.calc = LennardJones(sigma=AR_SIGMA, epsilon=AR_EPSILON, rc=AR_RC)
    path = tmp_path / 'md.traj'
    ReversibleVerlet(atoms, 2 * units.fs, trajectory=str(path),
                     loginterval=3, order=4).run(15)
    books = books_made(monkeypatch)
    assert cli.flipbook([str(path), '--index', '1', '--calculator',
                         'lj-argon', '--png', '3', '--out',
                         str(tmp_path / 'frame.png')]) == 0
    assert 'time step 2 fs, scheme velocity, order 4' in \
        capsys.readouterr().out
    assert books[0].stride == 3
    book, = books
    with Trajectory(str(path)) as frames:
        for frame in (3, 0, 2):
            book.goto(frame)
            assert np.array_equal(book.atoms.positions,
                                  frames[1 + frame].positions)
            assert np.array_equal(book.atoms.get_momenta(),
                                  frames[1 + frame].get_momenta())


@pytest.mark.parametrize('argv, message', [
    (['nowhere.traj', '--calculator', 'emt', '--png', '1', '--out', 'x.png'],
     'neither a scene'),
    (['ring', '--png', '2'], 'need --out'),
])
def test_command_line_errors(argv, message, capsys):
    with pytest.raises(SystemExit) as exit_:
        cli.flipbook(argv)
    assert exit_.value.code == 2
    assert message in capsys.readouterr().err


def test_command_line_file_needs_a_calculator(tmp_path, capsys):
    atoms = make_chain(2)
    atoms.write(tmp_path / 'chain.traj')
    with pytest.raises(SystemExit):
        cli.flipbook([str(tmp_path / 'chain.traj'), '--png', '1', '--out',
                      str(tmp_path / 'x.png')])
    assert '--calculator' in capsys.readouterr().err


def test_command_line_without_a_display_says_what_to_do(capsys):
    assert matplotlib.get_backend().lower() == 'agg'
    assert cli.flipbook(['ring']) == 2
    assert '--png FRAME --out FILE' in capsys.readouterr().err


@pytest.mark.parametrize('thermostat', ['ReversibleNose',
                                        'ReversibleLangevin'])
def test_a_thermostatted_run_is_browsed_back_to_its_first_frame_exactly(
        thermostat):
    from ase import units
    from ase.calculators.lj import LennardJones
    from ase_reversible import ReversibleLangevin, ReversibleNose
    from ase_reversible.app.systems import AR_EPSILON, AR_SIGMA, argon_cluster
    from ase.md.velocitydistribution import Stationary
    atoms = argon_cluster(2, 20)
    Stationary(atoms)
    atoms.calc = LennardJones(sigma=AR_SIGMA, epsilon=AR_EPSILON, rc=8.5)
    if thermostat == 'ReversibleNose':
        dyn = ReversibleNose(atoms, 5 * units.fs, 80, 100 * units.fs)
    else:
        dyn = ReversibleLangevin(atoms, 5 * units.fs, 80, 0.01 / units.fs,
                                 seed=3)
    start = dyn.counts
    book = Flipbook(dyn, stride=5)
    book.goto(40).back(25).forward(10).goto(0)
    assert book.frame == 0 and book.time == 0.0
    for name, counts in dyn.counts.items():
        assert np.array_equal(counts, start[name]), name
    book.goto(20)
    assert book.time > 0
    assert not np.array_equal(dyn.counts['position'], start['position'])


def langevin_trajectory(path, **kwargs):
    """A short ReversibleLangevin run at 2 fs written every 3 steps: not
    the command line's default dynamics (Verlet, 5 fs, one step)."""
    from ase_reversible import LennardJones, ReversibleLangevin
    atoms = argon_cluster(2, 60.0)
    atoms.calc = LennardJones(sigma=AR_SIGMA, epsilon=AR_EPSILON, rc=AR_RC)
    ReversibleLangevin(atoms, 2 * units.fs, temperature_K=60,
                       friction=0.01 / units.fs, seed=4, trajectory=str(path),
                       loginterval=3).run(9)
    return atoms


def test_a_thermostat_trajectory_is_refused_with_the_reason(tmp_path,
                                                            capsys):
    # Replayed by Verlet at 5 fs its frames would not be the file's; the
    # command says which dynamics wrote it, what replaying would need and
    # how to start a new run instead, and draws nothing.
    path = tmp_path / 'nvt.traj'
    langevin_trajectory(path)
    png = tmp_path / 'frame.png'
    with pytest.raises(SystemExit) as exit_:
        cli.flipbook([str(path), '--index', '1', '--calculator', 'lj-argon',
                      '--png', '2', '--out', str(png)])
    assert exit_.value.code == 2
    message = capsys.readouterr().err
    for part in ('written by ReversibleLangevin', 'timestep 2 fs', 'seed 4',
                 'interval 3', 'write_buffer', '--new-run'):
        assert part in message, part
    assert not png.exists()


def test_a_thermostat_frame_without_a_header_is_refused(tmp_path, capsys):
    # A frame saved on its own keeps the thermostat's restart record.
    atoms = langevin_trajectory(tmp_path / 'nvt.traj')
    atoms.write(tmp_path / 'frame.traj')
    with pytest.raises(SystemExit):
        cli.flipbook([str(tmp_path / 'frame.traj'), '--calculator',
                      'lj-argon', '--png', '1', '--out',
                      str(tmp_path / 'x.png')])
    assert "'langevin' section" in capsys.readouterr().err


def test_ase_dynamics_trajectories_are_refused(tmp_path, capsys):
    atoms = argon_cluster(2, 60.0)
    atoms.calc = AseLennardJones(sigma=AR_SIGMA, epsilon=AR_EPSILON,
                                 rc=AR_RC)
    path = tmp_path / 'md.traj'
    VelocityVerlet(atoms, 2 * units.fs, trajectory=str(path)).run(2)
    with pytest.raises(SystemExit):
        cli.flipbook([str(path), '--calculator', 'lj-argon', '--png', '1',
                      '--out', str(tmp_path / 'x.png')])
    assert 'written by VelocityVerlet (timestep 2 fs' in \
        capsys.readouterr().err


def test_new_run_starts_from_a_thermostat_frame_and_says_so(
        tmp_path, monkeypatch, capsys):
    path = tmp_path / 'nvt.traj'
    langevin_trajectory(path)
    books = books_made(monkeypatch)
    assert cli.flipbook([str(path), '--index', '1', '--calculator',
                         'lj-argon', '--new-run', '--timestep', '1',
                         '--png', '2', '--out',
                         str(tmp_path / 'frame.png')]) == 0
    assert '--new-run: a new ReversibleVerlet run from frame 1 at 1 fs, ' \
        '1 steps per frame' in capsys.readouterr().out
    book, = books
    assert type(book.dyn) is ReversibleVerlet
    assert book.dyn.dt == 1 * units.fs and book.time0 == 0.0
    with Trajectory(str(path)) as frames:
        assert np.array_equal(book.goto(0).atoms.positions,
                              frames[1].positions)


def test_a_structure_file_starts_a_new_run_and_says_so(tmp_path, capsys):
    atoms = argon_cluster(2, 60.0)
    atoms.write(tmp_path / 'start.traj')
    assert cli.flipbook([str(tmp_path / 'start.traj'), '--calculator',
                         'lj-argon', '--png', '1', '--out',
                         str(tmp_path / 'x.png')]) == 0
    assert 'no dynamics recorded in start.traj: a new ReversibleVerlet ' \
        'run from frame -1 at 5 fs, 1 steps per frame' in \
        capsys.readouterr().out
