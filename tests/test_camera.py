"""The camera tracker core on rendered frames: accuracy, calibration, rejections, several cameras."""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest

cv2 = pytest.importorskip("cv2")

from camera_support import (  # noqa: E402, F401 - the fixtures calibration, config, renderer
    CONFIG,
    calibrate_rendered,
    calibration_fixture,
    config_fixture,
    frame_of,
    fresh_renderer,
    renderer_for,
    renderer_fixture,
)
from vsfleet.tracker.calib import CalibrationError, FloorCalibration, Intrinsics, PinholeCamera, Reference  # noqa: E402
from vsfleet.tracker.calibrate import calibrate_frames  # noqa: E402
from vsfleet.tracker.markers import (  # noqa: E402
    CameraTracker,
    ConfigError,
    FrameError,
    config_from_dict,
    load_config,
    size_ok,
)
from vsfleet.tracker.render import (  # noqa: E402
    Renderer,
    reference_scene,
    render_frame,
    robot_scene,
    sim_camera_from_dict,
)
from vsfleet.geometry import angle_diff  # noqa: E402

# Measured with bench/camera.py (900 poses, 1280x720 over 3 x 2 m): position error max 0.62 mm,
# mean 0.17 mm; heading error max 10.7 mrad, mean 2.6 mrad. Bounds below carry a margin of about 3x.
POS_MAX_M = 0.002
POS_MEAN_M = 0.0006
TH_MAX_RAD = 0.03
TH_MEAN_RAD = 0.008


def random_poses(rng, robots):
    while True:
        xy = np.column_stack([rng.uniform(-0.4, 2.4, len(robots)), rng.uniform(-0.4, 1.4, len(robots))])
        d = np.linalg.norm(xy[:, None] - xy[None], axis=2) + 9 * np.eye(len(robots))
        if d.min() > 0.3:
            return {r: (x, y, rng.uniform(-math.pi, math.pi)) for r, (x, y) in zip(robots, xy)}


def errors(tracker, renderer, config, n_frames, seed):
    rng = np.random.default_rng(seed)
    pos, th = [], []
    robots = sorted(m.robot for m in config.markers.values())
    for k in range(n_frames):
        truth = random_poses(rng, robots)
        out = dict(tracker.process(renderer.render(robot_scene(config, renderer.spec, truth), k / 30), k / 30))
        assert set(out) == set(robots)
        for r, m in out.items():
            pos.append(math.hypot(m.x - truth[r][0], m.y - truth[r][1]))
            th.append(abs(angle_diff(m.th, truth[r][2])))
    return np.array(pos), np.array(th)


def test_the_detector_on_rendered_frames_is_within_the_measured_accuracy(config, renderer, calibration):
    assert calibration.model == "pinhole"
    assert calibration.error_mm["max"] < 3.0
    tracker = CameraTracker(config, calibration)
    pos, th = errors(tracker, renderer, config, 40, seed=7)
    print(f"position error mean {1000 * pos.mean():.2f} mm max {1000 * pos.max():.2f} mm; "
          f"heading error mean {1000 * th.mean():.2f} mrad max {1000 * th.max():.2f} mrad")
    assert pos.max() < POS_MAX_M and pos.mean() < POS_MEAN_M
    assert th.max() < TH_MAX_RAD and th.mean() < TH_MEAN_RAD
    assert tracker.rejections.count == 0


def test_a_homography_from_references_at_marker_height_is_as_accurate(config, renderer):
    z = config.marker_height_m
    refs = tuple(dataclasses.replace(r, z_m=z) for r in config.references)
    cfg = dataclasses.replace(config, references=refs)
    cal = calibrate_frames([renderer.render(reference_scene(cfg), 0.0)], cfg)
    assert cal.model == "homography" and cal.plane_z_m == z
    pos, th = errors(CameraTracker(cfg, cal), renderer, cfg, 15, seed=3)
    assert pos.max() < POS_MAX_M and th.max() < TH_MAX_RAD


def test_a_floor_homography_refuses_markers_above_the_floor(config, renderer):
    cal = calibrate_frames([renderer.render(reference_scene(config), 0.0)], config)
    assert cal.model == "homography" and cal.plane_z_m == 0.0
    with pytest.raises(CalibrationError, match="marker height"):
        CameraTracker(config, cal)


def test_one_seq_per_frame_with_src_and_capture_time(config, renderer, calibration):
    tracker = CameraTracker(config, calibration, src="camA")
    truth = {"r1": (0.3, 0.0, 0.1), "r2": (-0.15, 0.26, 1.0), "r3": (-0.15, -0.26, -2.0)}
    frame = renderer.render(robot_scene(config, renderer.spec, truth), 5.0)
    first = tracker.process(frame, 1234.5)
    second = tracker.process(frame, 1234.6)
    assert [r for r, _ in first] == ["r1", "r2", "r3"]
    assert {m.seq for _, m in first} == {1} and {m.seq for _, m in second} == {2}
    assert {m.src for _, m in first + second} == {"camA"}
    assert {m.t for _, m in first} == {1234.5}


def test_a_marker_mapping_to_no_robot_is_counted_and_not_published(config, renderer, calibration, caplog):
    tracker = CameraTracker(config, calibration)
    scene = robot_scene(config, renderer.spec, {"r1": (0.3, 0.0, 0.0)})
    stray = dataclasses.replace(scene[0], marker_id=17, x_m=1.2, y_m=0.8)
    refs = reference_scene(config)  # known references are not robots, and not rejections either
    out = tracker.process(renderer.render(scene + [stray] + refs, 0.0), 10.0)
    assert [r for r, _ in out] == ["r1"]
    assert tracker.rejections.count == 1
    assert "maps to no robot" in caplog.text


def test_a_marker_of_the_wrong_size_or_seen_twice_is_rejected(config, renderer, calibration):
    tracker = CameraTracker(config, calibration)
    scene = robot_scene(config, renderer.spec, {"r1": (0.3, 0.0, 0.0), "r2": (1.0, 0.5, 0.0)})
    big = dataclasses.replace(scene[1], size_m=0.16)
    twin = dataclasses.replace(scene[0], x_m=1.8)
    out = tracker.process(renderer.render([scene[0], twin, big], 0.0), 1.0)
    assert out == []
    assert tracker.rejections.by_key == {"marker": 2}


def test_unusable_frames_raise_frame_error_and_use_no_seq(config, calibration):
    tracker = CameraTracker(config, calibration)
    for bad in (np.zeros((0, 0), np.uint8), np.zeros((480, 640), np.uint8), np.zeros((720, 1280), np.float32),
                np.zeros((720, 1280, 2), np.uint8), None):
        with pytest.raises(FrameError):
            tracker.process(bad, 0.0)
    assert tracker.seq == 0
    assert tracker.process(np.full((720, 1280, 3), 128, np.uint8), 0.0) == []  # BGR is fine; nothing seen
    assert tracker.seq == 1


def test_the_tests_renderer_copies_render_what_a_new_renderer_does(config):
    """camera_support.fresh_renderer and frame_of stand for Renderer(spec, dictionary) and render_frame here: the same
    frames bit for bit, in the same sequence (a small image: the copies do not depend on its size)."""
    spec = dataclasses.replace(sim_camera_from_dict(config.sim_camera), width_px=320, height_px=180, f_px=200.0)
    poses = {"r1": (0.3, 0.02, 0.0), "r2": (1.0, 0.5, -1.0)}
    assert np.array_equal(frame_of(config, poses, 0.7, spec), render_frame(config, poses, 0.7, spec))
    new, copied = Renderer(spec, config.dictionary), fresh_renderer(spec, config.dictionary)
    scene = robot_scene(config, spec, poses)
    for t in (0.0, 0.1, 0.2):   # each frame draws its noise from the generator: the copy's runs as the new one's
        assert np.array_equal(copied.render(scene, t), new.render(scene, t))
    assert np.array_equal(fresh_renderer(spec, config.dictionary).render(scene, 0.0),
                          Renderer(spec, config.dictionary).render(scene, 0.0))   # not the used copy's state


def test_two_cameras_each_publish_their_own_src_and_seq_and_agree_on_the_overlap(config):
    left = dataclasses.replace(sim_camera_from_dict(config.sim_camera), position_m=(0.2, 0.5, 2.4),
                               look_at_m=(0.2, 0.5, 0.0), seed=1)
    right = dataclasses.replace(left, position_m=(1.8, 0.5, 2.4), look_at_m=(1.8, 0.55, 0.0), seed=2)
    truth = {"r1": (-0.2, 0.2, 0.5), "r2": (1.0, 0.5, -1.0), "r3": (2.2, 0.9, 3.0)}
    seen = {}
    for src, spec in (("camL", left), ("camR", right)):
        cfg = dataclasses.replace(config, src=src, sim_camera=dataclasses.asdict(spec))
        cal = calibrate_rendered(cfg, fresh_renderer(spec, cfg.dictionary))
        tracker = CameraTracker(cfg, cal)
        tracker.seq = {"camL": 100, "camR": 7}[src]  # trackers count frames independently
        seen[src] = dict(tracker.process(frame_of(cfg, truth, 0.0, spec), 50.0))
    assert set(seen["camL"]) == {"r1", "r2"} and set(seen["camR"]) == {"r2", "r3"}
    assert {(m.src, m.seq) for m in seen["camL"].values()} == {("camL", 101)}
    assert {(m.src, m.seq) for m in seen["camR"].values()} == {("camR", 8)}
    a, b = seen["camL"]["r2"], seen["camR"]["r2"]
    assert math.hypot(a.x - b.x, a.y - b.y) < POS_MAX_M and abs(angle_diff(a.th, b.th)) < TH_MAX_RAD
    assert math.hypot(a.x - 1.0, a.y - 0.5) < POS_MAX_M


def test_the_two_deploy_cameras_calibrate_on_their_own_and_agree_in_their_overlap():
    truth = {"r1": (0.5, 0.4, 0.7), "r2": (1.6, 1.1, -2.0), "r3": (-0.3, -0.2, 2.5)}
    seen = {}
    for path in (CONFIG, CONFIG.with_name("overhead-2.toml")):
        cfg = load_config(path)
        cal = calibrate_rendered(cfg, renderer_for(cfg))
        assert cal.error_mm["max"] < 3.0
        seen[cfg.src] = dict(CameraTracker(cfg, cal).process(frame_of(cfg, truth, 0.0), 1.0))
    assert set(seen) == {"cam1", "cam2"}
    for src, poses in seen.items():
        assert set(poses) == set(truth) and {m.src for m in poses.values()} == {src}
        for r, (x, y, th) in truth.items():
            assert math.hypot(poses[r].x - x, poses[r].y - y) < POS_MAX_M
            assert abs(angle_diff(poses[r].th, th)) < TH_MAX_RAD


def test_heading_offset_of_a_marker_mount(config, renderer, calibration):
    cfg = dataclasses.replace(config, markers={**config.markers, 1: dataclasses.replace(
        config.markers[1], heading_offset_rad=math.pi / 2)})
    tracker = CameraTracker(cfg, calibration)
    out = dict(tracker.process(frame_of(cfg, {"r1": (0.5, 0.5, 0.3)}, 0.0, renderer.spec), 0.0))
    assert abs(angle_diff(out["r1"].th, 0.3)) < TH_MAX_RAD


# ---------------------------------------------------------------- files


def test_calibration_round_trips_through_json(tmp_path, calibration):
    path = tmp_path / "cal.json"
    calibration.save(path)
    back = FloorCalibration.load(path)
    px = np.array([[100.0, 200.0], [640.0, 360.0], [1200.0, 700.0]])
    assert np.allclose(back.to_plane(px, 0.1), calibration.to_plane(px, 0.1), atol=1e-12)
    assert back.error_mm["mean"] == calibration.error_mm["mean"]


@pytest.mark.parametrize("text, message", [
    (None, "cannot read calibration file"),
    ("{not json", "not valid JSON"),
    ("[1, 2]", "expected a JSON object"),
    ('{"format": "other"}', "not a floor calibration"),
    ('{"format": "vsfleet-floor-calibration", "model": "homography", "image_size_px": [1280, 720]}',
     "missing field 'homography'"),
    ('{"format": "vsfleet-floor-calibration", "model": "homography", "image_size_px": [1280, 720], '
     '"homography": [[1, 0], [0, 1]]}', "shape"),
    ('{"format": "vsfleet-floor-calibration", "model": "homography", "image_size_px": [1280, 720], '
     '"homography": [[0, 0, 0], [0, 0, 0], [0, 0, 0]]}', "singular"),
    ('{"format": "vsfleet-floor-calibration", "model": "pinhole", "image_size_px": [1280, 720], '
     '"camera_matrix": [[800, 0, 640], [0, 800, 360], [0, 0, 1]], "rvec": [0, 0, "x"], "tvec": [0, 0, 1]}',
     "'rvec' must be numbers"),
    ('{"format": "vsfleet-floor-calibration", "model": "fisheye", "image_size_px": [1280, 720]}',
     "'model' must be"),
    ('{"format": "vsfleet-floor-calibration", "model": "pinhole", "image_size_px": [1280]}', "image_size_px"),
])
def test_a_malformed_calibration_file_is_a_clear_error(tmp_path, text, message):
    path = tmp_path / "cal.json"
    if text is not None:
        path.write_text(text)
    with pytest.raises(CalibrationError, match=message):
        FloorCalibration.load(path)


@pytest.mark.parametrize("doc, message", [
    ({"dictionary": "DICT_9X9_1"}, "unknown ArUco dictionary"),
    ({"markers": {"one": "r1"}}, "not an integer"),
    ({"markers": {"1_0": "r1"}}, "not an integer"),   # int("1_0") == 10
    ({"markers": {"+2": "r1"}}, "not an integer"),
    ({"markers": {" 3": "r1"}}, "not an integer"),
    ({"markers": {"\u0663": "r1"}}, "not an integer"),   # an Arabic-Indic 3: int() takes it
    ({"markers": {"1": "r1", "01": "r2"}}, "given twice"),
    ({"markers": {"1": {"robot": "r1", "heading_ofset_rad": 1.57}}}, r"marker 1: unknown keys \['heading_ofset_rad'\]"),
    ({"markers": {"1": {"robt": "r1"}}}, r"marker 1: unknown keys \['robt'\]"),
    ({"references": [{"id": 40, "x_m": 0, "y_m": 0, "size_m": 0.1, "z": 0.1}]},
     r"reference #1: unknown keys \['z'\]"),
    ({"references": [{"id": 40, "x_m": 0, "y_m": 0, "size_m": 0.1, "th_deg": 90}]}, "unknown keys"),
    ({"markers": {"99": "r1"}}, "not in DICT_4X4_50"),
    ({"markers": {"1": "r 1"}}, "robot must match"),
    ({"markers": {"1": "r1", "2": "r1"}}, "more than one marker"),
    ({"marker_size_m": -0.1}, "must be > 0"),
    ({"marker_height_m": "high"}, "finite number"),
    ({"references": [{"id": 40, "x_m": 0.0}]}, "missing 'y_m'"),
    ({"markers": {"1": "r1"}, "references": [{"id": 1, "x_m": 0, "y_m": 0, "size_m": 0.1}]}, "not worn"),
    ({"colour": "red"}, "unknown keys"),
])
def test_a_malformed_camera_config_is_a_clear_error(doc, message):
    with pytest.raises(ConfigError, match=message):
        config_from_dict({"src": "cam1", **doc})


def test_the_camera_config_needs_its_own_src():
    with pytest.raises(ConfigError, match="missing 'src'"):
        config_from_dict({"markers": {"1": "r1"}})
    cfg = config_from_dict({"src": "camB", "markers": {"1": "r1", "7": {"robot": "r2", "heading_offset_rad": 0.5}}})
    assert cfg.src == "camB" and set(cfg.markers) == {1, 7} and cfg.markers[7].heading_offset_rad == 0.5


def test_a_marker_size_check_never_passes_nan_or_inf():
    assert size_ok(0.10, 0.10, 0.25) and size_ok(0.124, 0.10, 0.25) and not size_ok(0.126, 0.10, 0.25)
    assert not size_ok(float("nan"), 0.10, 0.25)
    assert not size_ok(float("inf"), 0.10, 0.25)


def test_a_missing_or_broken_config_file_is_a_clear_error(tmp_path):
    with pytest.raises(ConfigError, match="cannot read camera config"):
        load_config(tmp_path / "nope.toml")
    bad = tmp_path / "bad.toml"
    bad.write_text("src = \n")
    with pytest.raises(ConfigError, match="not valid TOML"):
        load_config(bad)


def test_calibration_needs_three_references(config, renderer):
    cfg = dataclasses.replace(config, references=config.references[:2] + (Reference(47, 5.0, 5.0, 0.0, 0.15),))
    frame = renderer.render(reference_scene(dataclasses.replace(cfg, references=cfg.references[:2])), 0.0)
    with pytest.raises(CalibrationError, match=r"only 2 of 3 reference markers seen .* not seen: \[47\]"):
        calibrate_frames([frame], cfg)


def test_lens_distortion_is_undone_by_the_pinhole_calibration(config):
    # Measured over 600 poses with this barrel distortion: position max 2.0 mm, heading max 28 mrad
    # (the worst near the image's top edge); the bounds carry a 2x margin.
    spec = dataclasses.replace(sim_camera_from_dict(config.sim_camera), dist_coeffs=(-0.05, 0.01, 0.0, 0.0, 0.0))
    ren = fresh_renderer(spec, config.dictionary)
    cal = calibrate_frames([ren.render(reference_scene(config), 0.0)], config, ren.camera.intrinsics)
    pos, th = errors(CameraTracker(config, cal), ren, config, 15, seed=5)
    assert pos.max() < 0.004 and th.max() < 0.06
    undistorted = dataclasses.replace(cal.camera.intrinsics, dist_coeffs=np.zeros(5))
    wrong = calibrate_frames([ren.render(reference_scene(config), 0.0)], config, undistorted)
    assert wrong.error_mm["max"] > 5 * cal.error_mm["max"]  # ignoring the distortion shows in the report


# ---------------------------------------------------------------- calibrations that load but cannot be right


def pinhole_doc(camera: PinholeCamera) -> dict:
    return FloorCalibration("pinhole", 1280, 720, camera=camera).to_dict()


def floor_homography(camera: PinholeCamera) -> np.ndarray:
    """image px -> floor (x, y): the inverse of K [r1 r2 t] (no distortion)."""
    rot = camera.rotation
    return np.linalg.inv(camera.intrinsics.camera_matrix @ np.column_stack([rot[:, 0], rot[:, 1], camera.tvec]))


def tilted(down_rad: float, centre_m=(1.0, 0.5, 2.5)) -> PinholeCamera:
    """A camera looking along +y, ``down_rad`` below the horizontal, image up = world up."""
    a = down_rad
    rot = np.array([[1.0, 0.0, 0.0], [0.0, -math.sin(a), -math.cos(a)], [0.0, math.cos(a), -math.sin(a)]])
    k = np.array([[800.0, 0.0, 639.5], [0.0, 800.0, 359.5], [0.0, 0.0, 1.0]])
    return PinholeCamera(Intrinsics(1280, 720, k, np.zeros(5)), cv2.Rodrigues(rot)[0].ravel(),
                         -rot @ np.asarray(centre_m))


# 0.05 rad down: the rows above 360 - 800 tan(0.05) = 320 see above the horizon
TILTED = tilted(0.05)


@pytest.mark.parametrize("camera, message", [
    (PinholeCamera.look_at(1280, 720, 800.0, (1.0, 0.5, -2.5), (1.0, 0.5, 0.0)), "not above the floor"),
    (PinholeCamera.look_at(1280, 720, 800.0, (1.0, 0.5, 2.5), (1.0, 0.5, 5.0)), "does not look down"),
])
def test_a_calibration_with_the_camera_below_the_floor_or_looking_up_fails_to_load(tmp_path, camera, message):
    path = tmp_path / "cal.json"
    path.write_text(json.dumps(pinhole_doc(camera)))
    with pytest.raises(CalibrationError, match=message):
        FloorCalibration.load(path)


def test_a_camera_below_the_markers_plane_is_refused_by_the_tracker(config):
    from vsfleet.tracker.calib import calibration_from_dict

    low = calibration_from_dict(pinhole_doc(PinholeCamera.look_at(1280, 720, 800.0, (1.0, 0.5, 0.05),
                                                                  (1.0, 0.6, 0.0))))
    with pytest.raises(CalibrationError, match="not above the markers' plane"):
        CameraTracker(config, low)


def test_a_homography_with_the_horizon_in_the_image_fails_to_load():
    from vsfleet.tracker.calib import calibration_from_dict

    doc = {"format": "vsfleet-floor-calibration", "model": "homography", "image_size_px": [1280, 720],
           "plane_z_m": 0.0, "homography": floor_homography(TILTED).tolist()}
    with pytest.raises(CalibrationError, match="horizon inside the image"):
        calibration_from_dict(doc)
    overhead = PinholeCamera.look_at(1280, 720, 800.0, (1.0, 0.5, 2.5), (1.0, 0.6, 0.0))
    ok = calibration_from_dict({**doc, "homography": floor_homography(overhead).tolist()})
    assert np.allclose(ok.to_plane(np.array([[639.5, 359.5]]), 0.0), [[1.0, 0.6]], atol=1e-6)


def test_pixels_above_the_horizon_map_to_nan_not_to_a_point_behind_the_camera():
    from vsfleet.tracker.calib import calibration_from_dict

    cal = calibration_from_dict(pinhole_doc(TILTED))  # it loads: above the floor, looking (slightly) down
    xy = cal.to_plane(np.array([[640.0, 10.0], [640.0, 300.0], [640.0, 710.0]]), 0.1)
    assert np.all(np.isnan(xy[:2])) and np.all(np.isfinite(xy[2]))
    assert xy[2][1] > 0.5  # in front of the camera, along +y


def test_a_marker_whose_rays_miss_the_plane_is_rejected_not_published(config, renderer, caplog):
    from vsfleet.tracker.calib import calibration_from_dict

    tracker = CameraTracker(config, calibration_from_dict(pinhole_doc(TILTED)))
    frame = frame_of(config, {"r1": (1.0, 1.3, 0.0)}, 0.0, renderer.spec)  # near the image's top edge
    assert tracker.process(frame, 1.0) == []
    assert tracker.rejections.by_key == {"marker": 1}
    assert "do not meet the marker plane" in caplog.text
