"""The flipbook, headless: frames on demand, keys, pictures, command line.

Everything draws with matplotlib's Agg backend; key presses are real
matplotlib KeyEvents sent through a figure's callback registry, as a
window would send them.
"""

import matplotlib
import numpy as np
import pytest
from ase import units
from ase.calculators.emt import EMT
from ase.calculators.lj import LennardJones as AseLennardJones
from ase.io import Trajectory
from ase.md.velocitydistribution import Stationary
from ase.md.verlet import VelocityVerlet
from matplotlib.backend_bases import KeyEvent
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from PIL import Image

from ase_reversible import (LennardJones, ReversibleBussi,
                            ReversibleIsotropicNPT, ReversibleLangevin,
                            ReversibleNose, ReversibleNPT, ReversibleVerlet,
                            UnstableIntegrationError)
from ase_reversible.calculators import PendulumChain, make_chain
from ase_reversible.app import cli
from ase_reversible.app.flipbook import Flipbook
from ase_reversible.app.scenes import SCENES
from ase_reversible.app.view import AtomsView
from ase_reversible.md.replay import replay_from_header

from conftest import (AR_EPSILON, AR_RC, AR_SIGMA, DT, argon_cluster,
                      copper_bulk)
from tiers import tiered

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
    # What --calculator lj-argon attaches: the replay checks that it
    # reaches the file's next frame.
    atoms.calc = LennardJones(sigma=AR_SIGMA, epsilon=AR_EPSILON, rc=AR_RC)
    path = tmp_path / 'md.traj'
    ReversibleVerlet(atoms, DT, trajectory=str(path)).run(4)
    png = tmp_path / 'frame.png'
    assert cli.flipbook([str(path), '--index', '2', '--calculator',
                         'lj-argon', '--png', '3', '--out', str(png)]) == 0
    assert png.exists()


def test_a_flipbook_on_a_trajectory_frame_shows_the_frames_own_time(
        tmp_path, monkeypatch):
    atoms = argon_cluster(2, 60.0)
    atoms.calc = LennardJones(sigma=AR_SIGMA, epsilon=AR_EPSILON, rc=AR_RC)
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
    assert book.first == -1  # the file's frame 0, before frame 1
    with Trajectory(str(path)) as frames:
        for frame in (3, 0, -1, 2):
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
    message = capsys.readouterr().err
    assert 'written by VelocityVerlet (timestep 2 fs' in message
    assert '--new-run' in message


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


# -- each dynamics' own trajectory, replayed -----------------------------

def copper_cell():
    """32 Cu atoms in a periodic cell with ASE's EMT: what
    ``--calculator emt`` attaches, with a stress for the barostats."""
    atoms = copper_bulk((2, 2, 2), 300)
    Stationary(atoms)
    atoms.calc = EMT()
    return atoms


#: Each dynamics with a buffer or a state of its own, some settings away
#: from their defaults: a setting the replay dropped would show.
REPLAYED = {
    'ReversibleNose': lambda atoms, **kw: ReversibleNose(
        atoms, 2 * units.fs, 300, 50 * units.fs, tchain=3, **kw),
    'ReversibleLangevin': lambda atoms, **kw: ReversibleLangevin(
        atoms, 2 * units.fs, 300, 0.02 / units.fs, fixcm=False, seed=5,
        **kw),
    'ReversibleBussi': lambda atoms, **kw: ReversibleBussi(
        atoms, 2 * units.fs, 300, 40 * units.fs, seed=6, **kw),
    'ReversibleIsotropicNPT': lambda atoms, **kw: ReversibleIsotropicNPT(
        atoms, 2 * units.fs, 300, 1e4 * units.bar, 50 * units.fs,
        400 * units.fs, seed=7, **kw),
    'ReversibleNPT': lambda atoms, **kw: ReversibleNPT(
        atoms, 2 * units.fs, 300, 1e4 * units.bar, 50 * units.fs,
        400 * units.fs, seed=8, **kw),
    'ReversibleIsotropicNoseNPT': lambda atoms, **kw: ReversibleIsotropicNPT(
        atoms, 2 * units.fs, 300, 1e4 * units.bar, 50 * units.fs,
        400 * units.fs, thermostat='nose', tchain=3, **kw),
    'ReversibleNoseNPT': lambda atoms, **kw: ReversibleNPT(
        atoms, 2 * units.fs, 300, 1e4 * units.bar, 50 * units.fs,
        400 * units.fs, thermostat='nose', **kw),
}

#: The dynamics of REPLAYED that keep no information buffer.
DETERMINISTIC = ('ReversibleNose', 'ReversibleIsotropicNoseNPT',
                 'ReversibleNoseNPT')


def replayed_trajectory(tmp_path, name):
    """``REPLAYED[name]`` run 15 steps on :func:`copper_cell`, a frame every
    3 steps into ``md.traj`` (frames 0 to 5) and, for a dynamics with
    information buffers, the buffer file of each frame (``buffer-{step}
    .npz``); returns the trajectory's path."""
    path = tmp_path / 'md.traj'
    dyn = REPLAYED[name](copper_cell(), trajectory=str(path), loginterval=3)
    if name not in DETERMINISTIC:
        dyn.attach(lambda: dyn.write_buffer(
            tmp_path / f'buffer-{dyn.step_index}.npz'), interval=3)
    dyn.run(15)
    return path


def assert_frames_are_the_files(book, path, index, frames):
    """Frame ``k`` of ``book`` is frame ``index + k`` of the file at
    ``path``, bit for bit (positions, momenta, cell), visited in the order
    of ``frames``."""
    with Trajectory(str(path)) as written:
        for frame in frames:
            shown = exact_views(book.goto(frame).atoms)
            wanted = exact_views(written[index + frame])
            for what in shown:
                assert np.array_equal(shown[what], wanted[what]), \
                    (frame, what)


def exact_views(atoms):
    return {'positions': atoms.positions, 'momenta': atoms.get_momenta(),
            'cell': atoms.cell[:]}


# Two in the quick tier; Bussi's and the barostats' in the long one.
@pytest.mark.parametrize('name', tiered(list(REPLAYED), quick=[
    'ReversibleNose', 'ReversibleLangevin']))
def test_a_flipbook_replays_each_dynamics_own_trajectory_exactly(
        name, tmp_path, monkeypatch, capsys):
    # Frame 2 of 0..5 (step 6), with the buffer file written with it where
    # the dynamics keeps one: the frames shown are the file's, forward
    # past the frame and back past it to the file's first.
    path = replayed_trajectory(tmp_path, name)
    argv = [str(path), '--index', '2', '--calculator', 'emt', '--png', '1',
            '--out', str(tmp_path / 'frame.png')]
    if name not in DETERMINISTIC:
        argv += ['--buffer', str(tmp_path / 'buffer-6.npz')]
    books = books_made(monkeypatch)
    assert cli.flipbook(argv) == 0
    out = capsys.readouterr().out
    assert f'from the trajectory header: {name}, time step 2 fs' in out
    assert 'frame 0 is frame 2 of md.traj, back to frame -2' in out
    book, = books
    assert type(book.dyn).__name__ == name
    assert (book.stride, book.first) == (3, -2)
    assert_frames_are_the_files(book, path, 2, (3, 1, -2, 0, -1, 3, 2))


@pytest.mark.parametrize('name', ['ReversibleLangevin', 'ReversibleBussi',
                                  'ReversibleIsotropicNPT'])
def test_a_buffered_frame_without_its_buffer_is_refused_naming_it(
        name, tmp_path, capsys):
    # Without the buffer the continuation would differ from the file's
    # frames in the last bits and the way back would stop at the frame:
    # the command says which dynamics wrote the file, what the frame needs
    # and how to start a new run instead, and draws nothing.
    path = replayed_trajectory(tmp_path, name)
    png = tmp_path / 'frame.png'
    with pytest.raises(SystemExit) as exit_:
        cli.flipbook([str(path), '--index', '2', '--calculator', 'emt',
                      '--png', '1', '--out', str(png)])
    assert exit_.value.code == 2
    message = capsys.readouterr().err
    for part in (f'written by {name} (timestep 2 fs', 'interval 3',
                 '6 steps past its anchor', '--buffer FILE',
                 'write_buffer(path)', '--new-run'):
        assert part in message, part
    assert not png.exists()


def test_a_buffered_runs_first_frame_needs_no_buffer(tmp_path, monkeypatch,
                                                     capsys):
    # At the run's anchor the buffers are empty: the frame goes on exactly
    # without a file, and there is nothing before it.
    path = replayed_trajectory(tmp_path, 'ReversibleLangevin')
    books = books_made(monkeypatch)
    assert cli.flipbook([str(path), '--index', '0', '--calculator', 'emt',
                         '--png', '1', '--out',
                         str(tmp_path / 'frame.png')]) == 0
    assert "no frames before it (the run's anchor)" in \
        capsys.readouterr().out
    book, = books
    assert book.first == 0
    assert_frames_are_the_files(book, path, 0, (2, 5, 1, 0))


@pytest.mark.parametrize('buffer, message', [
    ('buffer-9.npz', 'written at step 9'),   # another frame's
    ('nowhere.npz', 'No such file'),
])
def test_a_buffer_that_is_not_the_frames_is_refused(buffer, message,
                                                    tmp_path, capsys):
    path = replayed_trajectory(tmp_path, 'ReversibleBussi')
    with pytest.raises(SystemExit):
        cli.flipbook([str(path), '--index', '2', '--calculator', 'emt',
                      '--buffer', str(tmp_path / buffer), '--png', '1',
                      '--out', str(tmp_path / 'frame.png')])
    error = capsys.readouterr().err
    assert f'--buffer {tmp_path / buffer} (for frame 2 of md.traj)' in error
    assert message in error


def test_a_buffer_for_dynamics_without_one_is_refused(tmp_path, capsys):
    path = replayed_trajectory(tmp_path, 'ReversibleNose')
    with pytest.raises(SystemExit):
        cli.flipbook([str(path), '--calculator', 'emt', '--buffer',
                      str(tmp_path / 'buffer.npz'), '--png', '1', '--out',
                      str(tmp_path / 'frame.png')])
    assert 'ReversibleNose, which keeps no buffer' in capsys.readouterr().err


def test_a_replay_refuses_another_time_step(tmp_path, capsys):
    # The file's frames are steps of its own time step; another one is a
    # new run, which --new-run asks for.
    path = replayed_trajectory(tmp_path, 'ReversibleNose')
    with pytest.raises(SystemExit):
        cli.flipbook([str(path), '--calculator', 'emt', '--timestep', '1',
                      '--png', '1', '--out', str(tmp_path / 'frame.png')])
    assert 'at its own time step (2 fs); pass --new-run' in \
        capsys.readouterr().err


def test_a_frame_of_another_run_than_the_headers_is_refused(tmp_path,
                                                            capsys):
    # A run appended to a file keeps the first run's header: its frames
    # would be replayed with the wrong dynamics.
    path = tmp_path / 'md.traj'
    atoms = copper_cell()
    ReversibleVerlet(atoms, 2 * units.fs, trajectory=str(path)).run(2)
    ReversibleNose(atoms, 2 * units.fs, 300, 50 * units.fs,
                   trajectory=str(path), append_trajectory=True).run(2)
    with pytest.raises(SystemExit):
        cli.flipbook([str(path), '--calculator', 'emt', '--png', '1',
                      '--out', str(tmp_path / 'frame.png')])
    assert 'md.traj: the header names ReversibleVerlet at 2 fs but the ' \
        "frame's restart record was written by ReversibleNose at 2 fs" in \
        capsys.readouterr().err


def test_a_header_the_class_cannot_take_is_refused():
    with pytest.raises(ValueError, match='lacks temperature_K, taut'):
        replay_from_header({'md-type': 'ReversibleBussi', 'timestep': 1.0})
    with pytest.raises(ValueError, match='does not take: tloop'):
        replay_from_header({'md-type': 'ReversibleVerlet', 'timestep': 1.0,
                            'tloop': 1})
    with pytest.raises(ValueError, match='written by Langevin .timestep 2 fs'):
        replay_from_header({'md-type': 'Langevin', 'timestep': 2 * units.fs})
    assert replay_from_header({}) is None


@pytest.mark.parametrize('index', tiered([2, -1], quick=[2]),
                         ids=['next-frame', 'last-frame'])
def test_a_replay_with_another_calculator_is_refused(index, tmp_path,
                                                     capsys):
    # The header gives the dynamics, not the calculator: frames replayed
    # with another one are not the file's, so the command checks the
    # file's neighbouring frame (the next, or the one before the last)
    # and refuses.
    path = replayed_trajectory(tmp_path, 'ReversibleNose')
    png = tmp_path / 'frame.png'
    with pytest.raises(SystemExit) as exit_:
        cli.flipbook([str(path), '--index', str(index), '--calculator',
                      'lj-argon', '--png', '1', '--out', str(png)])
    assert exit_.value.code == 2
    message = capsys.readouterr().err
    neighbour = 3 if index == 2 else 4
    for part in (f'does not reach its frame {neighbour} bit for bit',
                 '--calculator lj-argon', '--new-run'):
        assert part in message, part
    assert not png.exists()
