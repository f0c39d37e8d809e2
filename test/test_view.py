"""``cloth-lod view``: animations of a headless run and of a recorded bag, the
obstacle and grasp drawing shared with the still pictures, and bad input.

Frames are counted by opening the GIF with Pillow.  No timings are asserted.
"""

from __future__ import annotations

import math
import textwrap

import matplotlib
import numpy as np
import pytest
from PIL import Image

matplotlib.use("Agg")

from cloth_lod_ros.bag.analysis import read_session  # noqa: E402
from cloth_lod_ros.bag.rosbag import BagReader  # noqa: E402
from cloth_lod_ros.sim.config import load_scene, scene_from_dict  # noqa: E402
from cloth_lod_ros.tools import cli, plotting, view  # noqa: E402

SMALL = ["--size", "160x120", "--quiet"]
# A tiny scene with every drawable thing: a sphere under the cloth, a floor, a
# disc and a tilted box off to the side, and a grasp closed from the start.
SCENE = textwrap.dedent("""
    name: view_test
    cloth: {width: 1.0, height: 1.0, base_blocks: [4, 4], level: 3, origin: [-0.5, -0.5, 0.3]}
    material: {air_drag: 0.5}
    obstacles:
      - {type: sphere, name: ball, centre: [0, 0, 0], radius: 0.25}
      - {type: plane, name: floor, centre: [0, 0, -0.25], normal: [0, 0, 1]}
      - {type: disc, name: plate, centre: [0.6, 0.0, -0.2], radius: 0.1, half_height: 0.01}
      - {type: box, name: crate, centre: [-0.6, 0.2, -0.15], half_extents: [0.1, 0.1, 0.1],
         orientation: [0, 0, 0.3826834, 0.9238795]}
    grasps:
      - {name: hand, uv: [0.0, 1.0], close_time: 0.0}
    simulation: {time_step: 0.016666666666666666, duration: 0.2}
    lod: {enabled: true, initial_level: 2}
""")


def gif_frames(path) -> int:
    with Image.open(path) as image:
        assert image.format == "GIF"
        return image.n_frames


@pytest.fixture(scope="module")
def scene_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("scene") / "view_test.yaml"
    path.write_text(SCENE)
    return path


@pytest.fixture(scope="module")
def recorded(tmp_path_factory, scene_file):
    """A headless recording of the test scene (``run --bag``) and its final state."""
    out = tmp_path_factory.mktemp("bag")
    assert cli.main(["run", str(scene_file), "--no-png", "--quiet", "--out",
                     str(out / "state.npz"), "--bag", str(out / "session")]) == 0
    with np.load(out / "state.npz") as data:
        state = {k: data[k] for k in data.files}
    with BagReader(out / "session") as reader:
        markers = reader.topics["/cloth/markers"].message_count
    return out / "session", markers, state


# -- a headless run -----------------------------------------------------------------
def test_scene_animation_has_a_frame_every_1_over_fps(tmp_path, capsys):
    out = tmp_path / "anim.gif"
    code = cli.main(["view", "hang_two_corners", "--level", "2", "--duration", "0.2",
                     "--fps", "15", "--out", str(out), *SMALL])
    assert code == 0
    assert gif_frames(out) == math.floor(0.2 * 15 + 1e-9) + 1        # t = 0, 1/15, 2/15, 3/15
    assert f"wrote {out}: 4 frames" in capsys.readouterr().out
    with Image.open(out) as image:
        assert image.size == (160, 120)


def test_scene_animation_every_and_frames(scene_file):
    scene = load_scene(scene_file)
    every = view.animation_from_scene(scene, fps=30, every=2)
    assert every.source_frames == 7                                  # 0 .. 0.2 s at 30 fps
    assert [round(f.time, 6) for f in every.frames] == [0.0, round(2 / 30, 6),
                                                        round(4 / 30, 6), 0.2]
    assert every.max_level == 3 and [o.type for o in every.obstacles] == [
        "sphere", "plane", "disc", "box"]
    # The grasp closes in the first step: none at t = 0, then one.
    assert [len(f.grasps) for f in every.frames] == [0, 1, 1, 1]
    assert every.frames[-1].title.startswith("view_test   t = 0.20 s")


# -- a recording --------------------------------------------------------------------
def test_bag_animation_has_one_frame_per_recorded_marker_message(recorded, tmp_path):
    bag, markers, _ = recorded
    assert markers == 7                                   # 30 frames/s over 0.2 s, and t = 0
    out = tmp_path / "bag.gif"
    assert cli.main(["view", str(bag), "--out", str(out), *SMALL]) == 0
    assert gif_frames(out) == markers
    mcap = next(bag.glob("*.mcap"))                       # a bare .mcap file works too
    every = tmp_path / "every.gif"
    assert cli.main(["view", str(mcap), "--every", "3", "--out", str(every), *SMALL]) == 0
    assert gif_frames(every) == math.ceil(markers / 3)


def test_bag_frames_are_the_recorded_mesh_levels_and_grasps(recorded):
    bag, markers, state = recorded
    animation = view.animation_from_bag(bag)
    assert animation.source_frames == markers and len(animation.frames) == markers
    assert animation.name == "view_test" and animation.max_level == 3
    assert [o.name for o in animation.obstacles] == ["ball", "floor", "plate", "crate"]
    last = animation.frames[-1]
    # The surface marker's corners are the final state's triangles, and the
    # levels decoded from its colours are the simulator's.
    np.testing.assert_array_equal(last.corners, state["x"][state["triangles"]])
    np.testing.assert_array_equal(last.levels, state["levels"])
    assert last.time == pytest.approx(float(state["time"]))
    assert [len(f.grasps) for f in animation.frames] == [0] + [1] * (markers - 1)
    early = view.animation_from_bag(bag, duration=0.1)      # the first 0.1 s of the bag
    assert [round(f.time, 6) for f in early.frames] == [round(k / 30, 6) for k in range(4)]


def test_bag_and_headless_run_show_the_same_frames(recorded, scene_file):
    """The same scene simulated for the animation at the bag's 30 frames per
    second gives the recorded frames: same mesh, levels, grasps and times."""
    bag, _, _ = recorded
    recorded_frames = view.animation_from_bag(bag).frames
    simulated = view.animation_from_scene(load_scene(scene_file), fps=30).frames
    assert len(recorded_frames) == len(simulated)
    for a, b in zip(recorded_frames, simulated):
        np.testing.assert_array_equal(a.corners, b.corners)
        np.testing.assert_array_equal(a.levels, b.levels)
        np.testing.assert_array_equal(a.grasps, b.grasps)
        assert a.time == pytest.approx(b.time, abs=1e-9)
        assert a.title == b.title


def test_levels_from_area_when_the_markers_are_not_coloured_by_level(recorded):
    """A session recorded with ``colour_by: shading`` carries no levels in its
    colours; the triangle areas give them."""
    bag, _, state = recorded
    with BagReader(bag) as reader:
        scene = scene_from_dict(read_session(reader)["scene"])
    corners = state["x"][state["triangles"]]
    np.testing.assert_array_equal(view._levels_from_area(corners, scene), state["levels"])


# -- drawing ------------------------------------------------------------------------
def _axes(box, view_name="3d"):
    import matplotlib.pyplot as plt
    fig = plt.figure()
    ax = fig.add_subplot(projection="3d")
    plotting.setup_axes(ax, box, view_name)
    return fig, ax


def test_every_obstacle_type_is_drawn(scene_file):
    import matplotlib.pyplot as plt
    scene = load_scene(scene_file)
    box = plotting.view_box([np.array([[-0.8, -0.5, -0.3], [0.8, 0.5, 0.3]])], scene.obstacles)
    for name in plotting.VIEWS:
        fig, ax = _axes(box, name)
        artists = plotting.draw_obstacles(ax, scene.obstacles, box, name)
        kinds = [a.get_gid() for a in artists]
        if name == "3d":
            assert kinds == ["obstacle:sphere", "obstacle:plane", "obstacle:disc",
                             "obstacle:box"]
            assert [a.get_label() for a in artists] == ["ball", "floor", "plate", "crate"]
        assert "obstacle:sphere" in kinds
        assert all(a in ax.collections for a in artists)
        plt.close(fig)


def test_an_obstacle_outside_the_axes_is_not_drawn():
    import matplotlib.pyplot as plt
    scene = load_scene("drop_on_sphere")
    far = [o for o in scene.obstacles if o.type == "sphere"]
    box = (np.array([2.0, 2.0, 2.0]), np.array([3.0, 3.0, 3.0]))
    fig, ax = _axes(box)
    assert plotting.draw_obstacles(ax, far, box) == []
    plt.close(fig)


def test_obstacles_are_clipped_to_the_view_box():
    polygon = np.array([[-1.0, -1.0, 0.0], [1.0, -1.0, 0.0], [1.0, 1.0, 0.0], [-1.0, 1.0, 0.0]])
    box = (np.array([0.0, -0.5, -1.0]), np.array([2.0, 0.5, 1.0]))
    clipped = plotting.clip_polygon(polygon, box)
    assert clipped.min(axis=0)[:2].tolist() == [0.0, -0.5]
    assert clipped.max(axis=0)[:2].tolist() == [1.0, 0.5]
    assert plotting.clip_polygon(polygon + [0, 0, 5], box) is None


def test_view_box_holds_the_cloth_and_nearby_obstacles_only():
    cloth = np.array([[-0.5, -0.5, 0.0], [0.5, 0.5, 0.3]])
    scene = load_scene("table_drape")                  # a 1.2 m table, a floor 0.8 m down
    lo, hi = plotting.view_box([cloth], scene.obstacles)
    assert np.all(lo <= cloth[0]) and np.all(hi >= cloth[1])
    assert lo[2] < -0.3 + 1e-9                          # the table reaches down: clipped
    assert lo[2] > -0.8                                 # the floor is too far to stretch to
    assert np.all(hi - lo <= 1.7)                       # 1 m cloth + 30 % each side + pad


def test_faces_an_obstacle_hides_from_the_camera():
    scene = load_scene("drop_on_sphere")
    ball = [o for o in scene.obstacles if o.type == "sphere"]
    towards = plotting.camera_direction("top")          # looking down
    points = np.array([[0, 0, -0.3], [0, 0, 0.3], [0.4, 0, -0.1], [0, 0, 0.254]])
    hidden = plotting.hidden_points(points, ball, towards, reach=2.0)
    assert hidden.tolist() == [True, False, False, False]   # under it; above; beside; on it


def test_cloth_artists_show_grasps_pins_and_split_hidden_faces(scene_file):
    import matplotlib.pyplot as plt
    scene = load_scene(scene_file)
    # A flat cloth above the ball and its copy below it: the lower one is hidden.
    uv = np.array([[0, 0], [1, 0], [0, 1], [1, 1]], float) * 0.2 - 0.1
    top = np.column_stack([uv, np.full(4, 0.3)])
    positions = np.vstack([top, top - [0, 0, 0.6]])
    triangles = np.array([[0, 1, 2], [1, 3, 2], [4, 5, 6], [5, 7, 6]])
    frame = plotting.ClothFrame(positions, triangles, np.array([1, 1, 2, 2]), 0.5,
                                grasps=np.array([[0.1, 0.1, 0.3]]),
                                pins=np.array([[-0.1, -0.1, 0.3]]), title="t = 0.5 s")
    box = plotting.view_box([positions], scene.obstacles)
    fig, ax = _axes(box, "top")
    cloth = plotting.ClothArtists(ax, 3, scene.obstacles, "top")
    cloth.update(frame)
    assert len(cloth.front.get_facecolor()) == 2 and len(cloth.behind.get_facecolor()) == 2
    assert len(cloth.grasps.get_data_3d()[0]) == 1 and len(cloth.pins.get_data_3d()[0]) == 1
    assert cloth.title.get_text() == "t = 0.5 s"
    plt.close(fig)


def test_still_pictures_draw_obstacles_and_closed_grasps(scene_file, tmp_path, monkeypatch):
    drawn, grasps = [], []
    real_draw, real_update = plotting.draw_obstacles, plotting.ClothArtists.update

    def draw_obstacles(ax, obstacles, box, view_name="3d"):
        artists = real_draw(ax, obstacles, box, view_name)
        drawn.append([a.get_gid() for a in artists])
        return artists

    def update(self, frame):
        grasps.append(len(frame.grasps))
        return real_update(self, frame)

    monkeypatch.setattr(plotting, "draw_obstacles", draw_obstacles)
    monkeypatch.setattr(plotting.ClothArtists, "update", update)
    assert cli.main(["run", str(scene_file), "--frames", "2", "--quiet",
                     "--out", str(tmp_path / "s.npz")]) == 0
    assert (tmp_path / "s.png").is_file() and (tmp_path / "s_levels.png").is_file()
    assert len(drawn) == 3                          # two panels and the levels picture
    assert all("obstacle:sphere" in kinds for kinds in drawn)
    assert grasps == [0, 1, 1]                       # t = 0 (still open), final, final


# -- bad input ----------------------------------------------------------------------
@pytest.mark.parametrize("source, message", [
    ("no/such/bag_dir", "no such bag directory, .mcap file or scene file"),
    ("missing.mcap", "no such bag"),
    ("no_such_scene", "unknown scene 'no_such_scene'"),
    ("missing.yaml", "does not exist"),
])
def test_a_missing_source_is_exit_2_with_one_line(source, message, tmp_path, capsys,
                                                  monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert cli.main(["view", source, *SMALL]) == 2
    err = capsys.readouterr().err
    assert message in err and err.startswith("cloth-lod: ") and err.count("\n") == 1
    assert not (tmp_path / "out").exists()


def test_mp4_without_ffmpeg_is_exit_2_suggesting_gif(tmp_path, capsys, monkeypatch):
    from matplotlib import animation
    monkeypatch.setattr(animation.writers, "is_available", lambda name: False)
    started = []
    monkeypatch.setattr(view, "animation_from_scene", lambda *a, **k: started.append(1))
    assert cli.main(["view", "hang_two_corners", "--out", str(tmp_path / "a.mp4"),
                     *SMALL]) == 2
    err = capsys.readouterr().err
    assert "ffmpeg" in err and ".gif" in err and started == []   # refused before simulating


@pytest.mark.parametrize("extra, message", [
    (["--out", "a.avi"], "must be a .gif"),
    (["--size", "big"], "WIDTHxHEIGHT"),
    (["--size", "10x10"], "64 to 4096"),
    (["--every", "0"], "--every must be at least 1"),
    (["--fps", "0"], "--fps must be > 0"),
    (["--set", "material.density=-1"], "material.density"),
])
def test_bad_options_are_exit_2(extra, message, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert cli.main(["view", "hang_two_corners", "--quiet", *extra]) == 2
    assert message in capsys.readouterr().err


def test_scene_options_on_a_bag_are_exit_2(recorded, capsys):
    bag, _, _ = recorded
    assert cli.main(["view", str(bag), "--level", "4", *SMALL]) == 2
    assert "a recorded bag is shown as it is" in capsys.readouterr().err


def test_a_directory_that_is_not_a_bag_is_exit_2(tmp_path, capsys):
    assert cli.main(["view", str(tmp_path), *SMALL]) == 2
    assert "bag error" in capsys.readouterr().err
