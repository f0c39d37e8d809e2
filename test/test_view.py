"""``cloth-lod view``: videos of a recorded bag and of a headless run, the
obstacle and grasp drawing shared with the still pictures, and bad input.

Outside truths: the video's frame count and duration as ffmpeg (imageio-ffmpeg)
and Pillow read them back, against the bag's log times; obstacle poses and
CDR fields as rclpy decodes them; where matplotlib's own projection puts a
recorded pose.  No timings are asserted.
"""

from __future__ import annotations

import bisect
import dataclasses
import inspect
import json
import math
import textwrap
import tracemalloc

import matplotlib
import numpy as np
import pytest
from PIL import Image

matplotlib.use("Agg")

from cloth_lod_ros.bag.analysis import decode, read_session  # noqa: E402
from cloth_lod_ros.bag.rosbag import BagMessage, BagReader, BagWriter  # noqa: E402
from cloth_lod_ros.messages.markers import (cloth_markers, obstacle_markers,  # noqa: E402
                                            serialize_marker_array)
from cloth_lod_ros.sim.scene.config import load_scene, scene_from_dict, scene_to_dict  # noqa: E402
from cloth_lod_ros.tools import cli, plotting, view, view_bag  # noqa: E402

SMALL = ["--size", "160x120", "--quiet"]
# A tiny scene with every drawable thing: a sphere under the cloth, a floor, a
# disc, and a tilted box off to the side that a script moves 0.6 m along +y in
# the first 0.2 s; a grasp closed from the start.
SCENE = textwrap.dedent("""
    name: view_test
    cloth: {width: 1.0, height: 1.0, base_blocks: [4, 4], level: 3, origin: [-0.5, -0.5, 0.3]}
    material: {air_drag: 0.5}
    obstacles:
      - {type: sphere, name: ball, centre: [0, 0, 0], radius: 0.25}
      - {type: plane, name: floor, centre: [0, 0, -0.25], normal: [0, 0, 1]}
      - {type: disc, name: plate, centre: [0.6, 0.0, -0.2], radius: 0.1, half_height: 0.01}
      - {type: box, name: crate, centre: [-0.6, -0.3, -0.15], half_extents: [0.1, 0.1, 0.1],
         orientation: [0, 0, 0.3826834, 0.9238795], max_speed: 5.0,
         waypoints: [[0.0, -0.6, -0.3, -0.15], [0.2, -0.6, 0.3, -0.15]]}
    grasps:
      - {name: hand, uv: [0.0, 1.0], close_time: 0.0}
    simulation: {time_step: 0.016666666666666666, duration: 0.2}
    lod: {enabled: true, initial_level: 2}
""")
CRATE = 3                                    # index of the moving box in SCENE


def video(path) -> tuple[int, float, tuple]:
    """``(frames, fps, (width, height))`` of an MP4 as ffmpeg decodes it."""
    import imageio_ffmpeg
    reader = imageio_ffmpeg.read_frames(str(path))
    meta = next(reader)
    count = sum(1 for _ in reader)
    return count, float(meta["fps"]), tuple(meta["size"])


def gif(path) -> tuple[int, float, tuple]:
    """``(frames, total delay s, size)`` of a GIF as Pillow reads it."""
    with Image.open(path) as image:
        assert image.format == "GIF"
        total = 0
        for k in range(image.n_frames):
            image.seek(k)
            total += image.info["duration"]
        return image.n_frames, total / 1e3, image.size


def expected_frames(span_s: float, fps: float, speed: float = 1.0) -> int:
    """Output frames at t = 0, speed/fps, ... up to the span (both ends included)."""
    return math.floor(span_s * fps / speed + 1e-9) + 1


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


# -- a synthetic session ---------------------------------------------------------------
def _grid_cloth(n: int, width: float = 1.0):
    """A flat ``n`` x ``n`` particle grid in z = 0.3: positions ``(n*n, 3)`` and
    triangles ``(2 (n-1)^2, 3)``."""
    u = np.linspace(-width / 2, width / 2, n)
    x, y = np.meshgrid(u, u, indexing="ij")
    positions = np.column_stack([x.ravel(), y.ravel(), np.full(n * n, 0.3)])
    idx = np.arange(n * n).reshape(n, n)
    a, b = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel()
    c, d = idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    return positions, np.vstack([np.column_stack([a, b, c]), np.column_stack([a, c, d])])


def write_session(path, times_s, n: int = 6, crate_path=None, stats: bool = True) -> None:
    """A bag as the recorder writes one: ``/cloth/session`` (the test scene),
    then at each log time ``t0 + times_s[k]`` a ``cloth/markers`` frame (the grid
    cloth shifted by 0.1 m/s along x, all faces at level 3, the crate at
    ``crate_path(t)``) and, if ``stats``, a ``cloth/lod_stats`` with
    ``sim_time_s`` = 2 t (a simulation at twice real time)."""
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
    from rclpy.serialization import serialize_message
    from std_msgs.msg import String
    scene = load_scene_text()
    positions, triangles = _grid_cloth(n)
    levels = np.full(len(triangles), 3)
    t0 = 1_700_000_000 * 10**9
    with BagWriter(path) as writer:
        writer.add_topic("/cloth/session", "std_msgs/msg/String")
        writer.add_topic("/cloth/markers", "visualization_msgs/msg/MarkerArray")
        writer.add_topic("/cloth/lod_stats", "diagnostic_msgs/msg/DiagnosticArray")
        writer.write("/cloth/session", serialize_message(String(data=json.dumps(
            {"format": 1, "scene": scene_to_dict(scene)}))), t0)
        for t in times_s:
            obstacles = list(scene.obstacles)
            if crate_path is not None:
                obstacles[CRATE] = dataclasses.replace(
                    obstacles[CRATE], centre=tuple(float(c) for c in crate_path(t)))
            specs = cloth_markers(positions + [0.1 * t, 0, 0], triangles, levels, 3, "world")
            specs += obstacle_markers(obstacles, "world")
            stamp = t0 + int(round(t * 1e9))
            writer.write("/cloth/markers", serialize_marker_array(specs), stamp)
            if stats:
                sim_time = KeyValue(key="sim_time_s", value=repr(float(2 * t)))
                status = DiagnosticStatus(name="cloth_lod: simulation", level=bytes([0]),
                                          values=[sim_time])
                writer.write("/cloth/lod_stats",
                             serialize_message(DiagnosticArray(status=[status])), stamp)


def load_scene_text():
    """The test scene, from its YAML text."""
    import yaml
    return scene_from_dict(yaml.safe_load(SCENE))


# A session of 3.05 s recorded at an uneven ~20 Hz (as a loaded node publishes).
RNG_TIMES = np.cumsum(np.r_[0.0, np.random.default_rng(7).uniform(0.02, 0.08, 200)])
UNEVEN = RNG_TIMES[RNG_TIMES <= 3.05]
UNEVEN[-1] = 3.05


@pytest.fixture(scope="module")
def uneven(tmp_path_factory):
    path = tmp_path_factory.mktemp("uneven") / "session"
    write_session(path, UNEVEN, crate_path=lambda t: (-0.6, -0.3 + 0.2 * t, -0.15))
    return path


# -- reading recorded messages ------------------------------------------------------------
def test_marker_array_parser_reads_what_rclpy_writes():
    """Every field the picture uses, after a marker that fills the fields it
    skips (text, mesh, texture, uv coordinates), as rclpy serialises them."""
    from geometry_msgs.msg import Point
    from rclpy.serialization import serialize_message
    from std_msgs.msg import ColorRGBA
    from visualization_msgs.msg import Marker, MarkerArray, UVCoordinate
    busy = Marker(ns="label", id=7, type=Marker.TEXT_VIEW_FACING, action=Marker.ADD,
                  text="héllo", mesh_resource="package://x/y.dae", texture_resource="t",
                  uv_coordinates=[UVCoordinate(u=0.25, v=0.5)] * 3)
    busy.texture.format = "png"
    busy.texture.data = bytes(range(5))
    busy.mesh_file.filename = "m.stl"
    busy.mesh_file.data = bytes(range(3))
    busy.header.frame_id = "odd_length"
    surface = Marker(ns="surface", id=0, type=Marker.TRIANGLE_LIST, action=Marker.ADD)
    surface.pose.position.x, surface.pose.position.y, surface.pose.position.z = 1.0, -2.0, 3.5
    surface.pose.orientation.z, surface.pose.orientation.w = 0.6, 0.8
    surface.scale.x = 0.5
    corners = np.random.default_rng(1).normal(size=(6, 3))
    surface.points = [Point(x=a, y=b, z=c) for a, b, c in corners]
    surface.colors = [ColorRGBA(r=0.125 * k, g=0.5, b=1.0, a=1.0) for k in range(6)]
    parsed = view_bag.parse_marker_array(serialize_message(MarkerArray(markers=[busy, surface])))
    assert [(m.ns, m.id, m.type, m.action) for m in parsed] == [
        ("label", 7, Marker.TEXT_VIEW_FACING, Marker.ADD),
        ("surface", 0, Marker.TRIANGLE_LIST, Marker.ADD)]
    s = parsed[1]
    assert s.position.tolist() == [1.0, -2.0, 3.5]
    assert s.orientation.tolist() == [0.0, 0.0, 0.6, 0.8]
    assert s.scale.tolist() == [0.5, 0.0, 0.0]
    np.testing.assert_array_equal(s.points, corners)
    np.testing.assert_array_equal(s.colors[:, 0], np.float32(0.125) * np.arange(6))
    with pytest.raises(ValueError, match="unreadable MarkerArray"):
        view_bag.parse_marker_array(serialize_message(MarkerArray(markers=[surface]))[:-40])


def test_diagnostics_and_string_parsers_read_what_rclpy_writes():
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
    from rclpy.serialization import serialize_message
    from std_msgs.msg import String
    status = DiagnosticStatus(name="n", message="running", hardware_id="hw", level=bytes([1]),
                              values=[KeyValue(key="sim_time_s", value="1.25"),
                                      KeyValue(key="triangles", value="512")])
    array = DiagnosticArray(status=[status])
    array.header.frame_id = "world"
    data = serialize_message(array)
    assert view_bag.parse_diagnostic_values(data) == {"sim_time_s": "1.25", "triangles": "512"}
    assert view_bag.parse_diagnostic_values(serialize_message(DiagnosticArray())) == {}
    assert view_bag.parse_string(serialize_message(String(data='{"a": 1}'))) == '{"a": 1}'


def test_each_output_frame_shows_the_latest_recorded_frame_at_its_time():
    """Output frame k shows the last recorded frame logged at or before
    t0 + k speed/fps, with that frame's statistics; nothing past the
    last recorded frame or past --duration."""
    times = (10**9 + np.round(UNEVEN * 1e9)).astype(int).tolist()
    messages = []
    for k, t in enumerate(times):
        messages.append(BagMessage("/cloth/markers", "", t, f"m{k}".encode()))
        messages.append(BagMessage("/cloth/grid", "", t, b"ignored"))
        messages.append(BagMessage("/cloth/lod_stats", "", t, f"s{k}".encode()))
    for fps, speed, duration in ((15, 1, None), (7, 2.5, None), (30, 1, 1.0)):
        duration_ns = None if duration is None else int(duration * 1e9)
        got = list(view_bag.select_frames(iter(messages), "/cloth/markers", "/cloth/lod_stats",
                                          view_bag.frame_offsets(fps, speed), duration_ns))
        span = duration if duration is not None else UNEVEN[-1]
        assert len(got) == expected_frames(span, fps, speed)
        for k, (offset, time_ns, markers, stats) in enumerate(got):
            assert offset == round(k * 1e9 * speed / fps)
            index = bisect.bisect_right(times, times[0] + offset) - 1
            assert (time_ns, markers, stats) == (times[index], f"m{index}".encode(),
                                                 f"s{index}".encode())


# -- videos of a bag ----------------------------------------------------------------------
@pytest.mark.parametrize("fps, speed", [(12, 1.0), (10, 2.0)])
def test_mp4_lasts_as_long_as_the_recording(uneven, tmp_path, fps, speed, capsys):
    out = tmp_path / "session.mp4"
    assert cli.main(["view", str(uneven), "--out", str(out), "--fps", str(fps),
                     "--speed", str(speed), "--size", "160x120"]) == 0
    frames, rate, size = video(out)
    assert rate == fps and size == (160, 120)
    assert frames == expected_frames(UNEVEN[-1], fps, speed)
    # The video plays the session's log-time span at the given speed.
    assert frames / fps == pytest.approx(UNEVEN[-1] / speed, abs=1 / fps)
    assert f"for {UNEVEN[-1]:.2f} s of recording (bag log time)" in capsys.readouterr().out


def test_gif_is_decimated_and_still_plays_in_real_time(uneven, tmp_path):
    out = tmp_path / "session.gif"
    assert cli.main(["view", str(uneven), "--out", str(out), "--fps", "30", "--quiet"]) == 0
    frames, seconds, size = gif(out)
    assert size == view.DEFAULT_SIZE["gif"]
    # 10 frames per second at most; equal consecutive frames are merged, so
    # the delays, not the frame count, carry the time.
    shown = expected_frames(UNEVEN[-1], view.GIF_MAX_FPS)
    assert frames <= shown
    assert seconds == pytest.approx(shown / view.GIF_MAX_FPS, abs=0.011)
    with Image.open(out) as image:                       # the first frame is whole
        assert len(image.convert("RGB").getcolors(maxcolors=256) or ()) <= view.GIF_COLOURS


def test_png_contact_sheet_has_the_tiles_evenly_in_time(uneven, tmp_path, capsys):
    out = tmp_path / "sheet.png"
    assert cli.main(["view", str(uneven), "--out", str(out), "--tiles", "6",
                     "--size", "100x80"]) == 0
    with Image.open(out) as image:
        assert image.size == (4 * 100, 2 * 80)
    assert "6 tiles over 3.05 s" in capsys.readouterr().out


def test_bag_frames_carry_the_simulated_time_and_recorded_obstacle_poses(uneven):
    with BagReader(uneven) as reader:
        source = view_bag.open_bag(reader)
        frames = list(view_bag.bag_frames(reader, source, view_bag.frame_offsets(4)))
    times = 10**9 * 1_700_000_000 + np.round(UNEVEN * 1e9).astype(int)
    assert len(frames) == expected_frames(UNEVEN[-1], 4)
    for offset, time_ns, frame in frames:
        t = (time_ns - times[0]) * 1e-9
        assert frame.time == pytest.approx(2 * t)                # sim_time_s of the frame
        assert frame.obstacles[CRATE].centre == pytest.approx((-0.6, -0.3 + 0.2 * t, -0.15))
        assert frame.positions[:, 0].min() == pytest.approx(-0.5 + 0.1 * t)
        assert frame.levels.tolist() == [3] * len(frame.triangles)


def test_the_frame_iterator_holds_a_constant_number_of_frames(tmp_path):
    """Memory does not grow with the bag: the peak of Python allocations while
    every frame of a 400-frame bag is parsed stays near that of a 40-frame
    bag, and far below what holding the frames would need."""
    peaks = {}
    for count in (40, 400):
        path = tmp_path / f"bag{count}"
        write_session(path, np.arange(count) / 30.0, n=21, stats=False)
        with BagReader(path) as reader:
            source = view_bag.open_bag(reader)
            frames = view_bag.bag_frames(reader, source, view_bag.frame_offsets(30))
            assert inspect.isgenerator(frames)
            tracemalloc.start()
            seen = sum(1 for _ in frames)
            peaks[count] = tracemalloc.get_traced_memory()[1]
            tracemalloc.stop()
        assert seen == count
    frame_bytes = 800 * 3 * (24 + 16)                     # 800 triangles: points + colours
    assert peaks[400] < 1.5 * peaks[40] + 2**20
    assert peaks[400] < 400 * frame_bytes / 4


def test_a_moving_obstacle_is_drawn_where_the_bag_says(recorded):
    """The crate moves along +y during the recording: in the first and last
    frames its pixels (those that change when it is hidden) lie where
    matplotlib's projection puts its recorded centres (decoded with rclpy)."""
    from mpl_toolkits.mplot3d import proj3d
    bag, markers, _ = recorded
    with BagReader(bag) as reader:
        recorded_centres = []
        for m in reader.messages(["/cloth/markers"]):
            crate = [k for k in decode(m.data, m.type_name).markers if k.ns == "crate"][0]
            recorded_centres.append([crate.pose.position.x, crate.pose.position.y,
                                     crate.pose.position.z])
        source = view_bag.open_bag(reader)
        view_bag.scan(reader, source, view_bag.frame_offsets(30))
        box = plotting.view_box([source.box_points], source.planes,
                                extents=source.obstacle_extents)
        frames = [f for _, _, f in view_bag.bag_frames(reader, source, view_bag.frame_offsets(30))]
    assert len(frames) == markers
    first, last = np.array(recorded_centres[0]), np.array(recorded_centres[-1])
    assert last[1] - first[1] > 0.3                       # it did move along +y
    renderer = view.Renderer((320, 240), box, 3, source.scene.obstacles, "top")
    ax, crate = renderer.axes, renderer.obstacles.artists[CRATE]
    measured, expected = [], []
    for frame, centre in ((frames[0], first), (frames[-1], last)):
        with_crate = renderer.draw(frame).copy()
        crate.set_visible(False)
        renderer.canvas.draw()                            # a full draw without it
        without = np.asarray(renderer.canvas.buffer_rgba()).copy()
        crate.set_visible(True)
        rows, cols = np.nonzero(np.any(with_crate != without, axis=2))
        assert len(rows) > 50
        measured.append(np.array([cols.mean(), rows.mean()]))
        x, y, _ = proj3d.proj_transform(*centre, ax.M)
        px, py = ax.transData.transform((x, y))
        expected.append(np.array([px, 240 - py]))         # image rows grow downwards
    moved, predicted = measured[1] - measured[0], expected[1] - expected[0]
    assert np.dot(moved, predicted) / np.linalg.norm(moved) / np.linalg.norm(predicted) > 0.99
    for m, e in zip(measured, expected):
        assert np.linalg.norm(m - e) < 4                  # pixels


def test_blitted_frames_equal_full_draws(recorded):
    """A frame drawn on the kept background is the picture a full draw makes."""
    bag, _, _ = recorded
    with BagReader(bag) as reader:
        source = view_bag.open_bag(reader)
        view_bag.scan(reader, source, view_bag.frame_offsets(30))
        frames = [f for _, _, f in view_bag.bag_frames(reader, source, view_bag.frame_offsets(30))]
    box = plotting.view_box([source.box_points], source.planes, extents=source.obstacle_extents)
    renderer = view.Renderer((320, 240), box, 3, source.scene.obstacles)
    renderer.draw(frames[0])
    blitted = renderer.draw(frames[-1]).copy()
    renderer.canvas.draw()
    full = np.asarray(renderer.canvas.buffer_rgba())
    np.testing.assert_array_equal(blitted, full)


def test_bag_frames_are_the_recorded_mesh_levels_and_grasps(recorded):
    bag, markers, state = recorded
    with BagReader(bag) as reader:
        source = view_bag.open_bag(reader)
        frames = [f for _, _, f in view_bag.bag_frames(reader, source, view_bag.frame_offsets(30))]
    assert len(frames) == markers == 7                    # 30 frames/s over 0.2 s, and t = 0
    assert source.scene.name == "view_test"
    assert [o.name for o in frames[0].obstacles] == ["ball", "floor", "plate", "crate"]
    last = frames[-1]
    # The surface marker's corners are the final state's triangles, and the
    # levels decoded from its colours are the simulator's.
    np.testing.assert_array_equal(last.corners, state["x"][state["triangles"]])
    np.testing.assert_array_equal(last.levels, state["levels"])
    assert last.time == pytest.approx(float(state["time"]))
    assert [len(f.grasps) for f in frames] == [0] + [1] * (markers - 1)


def test_bag_and_headless_run_show_the_same_frames(recorded, scene_file):
    """The same scene simulated for the video at the bag's 30 frames per second
    gives the recorded frames: same mesh, levels, grasps, obstacles and times."""
    bag, _, _ = recorded
    with BagReader(bag) as reader:
        source = view_bag.open_bag(reader)
        recorded_frames = [f for _, _, f in view_bag.bag_frames(
            reader, source, view_bag.frame_offsets(30))]
    simulated = view.animation_from_scene(load_scene(scene_file), fps=30).frames
    assert len(recorded_frames) == len(simulated)
    for a, b in zip(recorded_frames, simulated):
        np.testing.assert_array_equal(a.corners, b.corners)
        np.testing.assert_array_equal(a.levels, b.levels)
        np.testing.assert_array_equal(a.grasps, b.grasps)
        assert a.time == pytest.approx(b.time, abs=1e-9)
        assert a.title == b.title
        for oa, ob in zip(a.obstacles, b.obstacles):
            np.testing.assert_allclose(oa.centre, ob.centre, atol=1e-12)
            np.testing.assert_allclose(oa.orientation, ob.orientation, atol=1e-12)
            np.testing.assert_allclose(oa.normal, ob.normal, atol=1e-12)
            np.testing.assert_allclose(oa.axis, ob.axis, atol=1e-12)


def test_levels_from_area_when_the_markers_are_not_coloured_by_level(recorded):
    """A session recorded with ``colour_by: shading`` carries no levels in its
    colours; the triangle areas give them."""
    bag, _, state = recorded
    with BagReader(bag) as reader:
        scene = scene_from_dict(read_session(reader)["scene"])
    corners = state["x"][state["triangles"]]
    np.testing.assert_array_equal(view_bag.levels_from_area(corners, scene), state["levels"])


# -- a headless run -----------------------------------------------------------------------
def test_scene_video_has_a_frame_every_speed_over_fps(tmp_path, capsys):
    out = tmp_path / "anim.mp4"
    code = cli.main(["view", "hang_two_corners", "--level", "2", "--duration", "0.2",
                     "--fps", "15", "--out", str(out), "--size", "160x120"])
    assert code == 0
    assert video(out) == (expected_frames(0.2, 15), 15.0, (160, 120))   # t = 0, 1/15, ...
    assert f"wrote {out}: 4 frames, 0.27 s at 15 fps for 0.20 s of simulated time" \
        in capsys.readouterr().out


def test_scene_frames_follow_fps_speed_grasps_and_obstacles(scene_file):
    scene = load_scene(scene_file)
    fast = view.animation_from_scene(scene, fps=15, speed=2)       # a frame every 2/15 s
    assert [round(f.time, 6) for f in fast.frames] == [0.0, round(2 / 15, 6)]
    every = view.animation_from_scene(scene, fps=30)
    assert len(every.frames) == 7                                  # 0 .. 0.2 s at 30 fps
    assert every.max_level == 3 and [o.type for o in every.obstacles] == [
        "sphere", "plane", "disc", "box"]
    # The grasp closes in the first step: none at t = 0, then one.
    assert [len(f.grasps) for f in every.frames] == [0] + [1] * 6
    # The crate follows its script: 3 m/s along +y from t = 0.
    for f in every.frames:
        assert f.obstacles[CRATE].centre[1] == pytest.approx(-0.3 + 3.0 * f.time, abs=1e-9)
    assert every.frames[-1].title.startswith("view_test   t = 0.20 s")


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


# -- bad input and the output format ------------------------------------------------------
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


def test_mp4_without_imageio_ffmpeg_is_exit_2_suggesting_gif(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(view, "ffmpeg_available", lambda: False)
    started = []
    monkeypatch.setattr(view, "animation_from_scene", lambda *a, **k: started.append(1))
    assert cli.main(["view", "hang_two_corners", "--out", str(tmp_path / "a.mp4"),
                     *SMALL]) == 2
    err = capsys.readouterr().err
    assert "imageio-ffmpeg" in err and ".gif" in err and started == []   # refused before simulating


def test_default_output_is_mp4_or_else_gif_with_a_message(uneven, tmp_path, capsys,
                                                          monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert cli.main(["view", str(uneven), "--duration", "0.5", "--size", "96x64"]) == 0
    assert video(tmp_path / "out" / "session.mp4")[0] == expected_frames(0.5, 15)
    monkeypatch.setattr(view, "ffmpeg_available", lambda: False)
    assert cli.main(["view", str(uneven), "--duration", "0.5", "--size", "96x64"]) == 0
    assert "imageio-ffmpeg is not installed: writing a GIF" in capsys.readouterr().out
    assert gif(tmp_path / "out" / "session.gif")[1] == pytest.approx(
        expected_frames(0.5, 10) / 10, abs=0.011)


@pytest.mark.parametrize("extra, message", [
    (["--out", "a.avi"], "must be a .mp4 video, a .gif"),
    (["--size", "big"], "WIDTHxHEIGHT"),
    (["--size", "10x10"], "64 to 4096"),
    (["--fps", "0"], "--fps must be > 0"),
    (["--speed", "-1"], "--speed must be > 0"),
    (["--tiles", "0"], "--tiles must be at least 1"),
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
