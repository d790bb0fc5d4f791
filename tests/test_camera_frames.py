"""The camera loop of `vsfleet run --tracker camera`: one frame message per camera frame, the render
loop prepared from a camera config, and the tracker command `vsfleet run` starts."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest

cv2 = pytest.importorskip("cv2")

from camera_support import (  # noqa: E402, F401 - the fixtures calibration, config, renderer
    CONFIG,
    TRUTH,
    calibration_fixture,
    config_fixture,
    renderer_fixture,
)
from vsfleet.zglue.lifecycle import StopFlag  # noqa: E402
from vsfleet.fleetctl.run import DEFAULT_CAMERA, tracker_args  # noqa: E402
from vsfleet.zglue.scenario_file import load_scenario  # noqa: E402
from vsfleet.tracker.calib import FloorCalibration  # noqa: E402
from vsfleet.tracker.calibrate import calibrate_render  # noqa: E402
from vsfleet.tracker.camera import build_parser, run_loop  # noqa: E402
from vsfleet.tracker.markers import CameraTracker, ConfigError  # noqa: E402
from vsfleet.tracker.render import robot_scene  # noqa: E402
from vsfleet.scenario import ScenarioError, scenario_from_dict  # noqa: E402
from vsfleet.wire import decode_frame, encode_frame  # noqa: E402

ROOT = Path(__file__).parent.parent
CAMERA_SCENARIO = ROOT / "scenarios" / "camera-triangle.toml"
SIM_SCENARIO = ROOT / "scenarios" / "paper-triangle.toml"


class Frames:
    """A source that plays (image, t) pairs, then stops the loop."""

    def __init__(self, items, stop):
        self.items, self.stop = list(items), stop

    def read(self):
        if not self.items:
            self.stop.set()
            return None
        return self.items.pop(0)

    def close(self):
        pass


def test_every_camera_frame_is_published_once_as_a_frame_with_the_poses_it_gave(config, renderer, calibration):
    moved = {"r1": (0.5, 0.1, 0.3), "r2": (0.1, 0.4, -0.2), "r3": (0.2, -0.2, 1.0)}
    only_r2 = {"r2": TRUTH["r2"]}
    images = [(renderer.render(robot_scene(config, renderer.spec, poses), t), t)
              for poses, t in ((TRUTH, 10.0), (moved, 10.04), ({}, 10.07), (only_r2, 10.1))]
    images.insert(2, (np.zeros((10, 10), np.uint8), 10.05))  # unusable: no frame, no seq
    stop = StopFlag(install_signals=False)
    poses, frames = [], []
    tracker = CameraTracker(config, calibration)
    stats = run_loop(lambda: Frames(images, stop), tracker, lambda r, m: poses.append((r, m)), stop,
                     publish_frame=frames.append)
    assert stats.frames == 4 and stats.bad_frames == 1
    assert [(f.seq, f.t, f.src) for f in frames] == [(1, 10.0, "cam1"), (2, 10.04, "cam1"), (3, 10.07, "cam1"),
                                                     (4, 10.1, "cam1")]
    assert [sorted(f.poses) for f in frames] == [["r1", "r2", "r3"], ["r1", "r2", "r3"], [], ["r2"]]
    for f in frames:  # the frame holds exactly the poses published for it, and survives the wire
        assert f.poses == {r: (m.x, m.y, m.th) for r, m in poses if m.seq == f.seq}
        assert decode_frame(encode_frame(f)) == f
    for truth, f in ((TRUTH, frames[0]), (moved, frames[1])):
        for r, (x, y, th) in truth.items():
            assert math.hypot(f.poses[r][0] - x, f.poses[r][1] - y) < 0.003
            assert abs(math.remainder(f.poses[r][2] - th, math.tau)) < 0.02


@pytest.mark.integration  # `vsfleet tracker calibrate --source render` runs as a child
def test_the_render_loop_is_calibrated_on_the_rendered_references_and_runs_as_the_camera_tracker(tmp_path):
    sim = load_scenario(SIM_SCENARIO)
    args = tracker_args(sim, str(SIM_SCENARIO), "camera", str(CONFIG), tmp_path)  # `vsfleet tracker calibrate`
    cal = FloorCalibration.load(tmp_path / "calibration.json")
    assert cal.error_mm["max"] < 3.0  # mm on the floor (measured 1.7 mm)
    parsed = build_parser().parse_args(args[1:])
    assert (parsed.source, Path(parsed.camera), Path(parsed.calibration)) == (
        "render", CONFIG, tmp_path / "calibration.json")


def test_the_render_loop_refuses_a_robot_the_camera_cannot_see(tmp_path):
    with pytest.raises(ConfigError, match=r"no marker maps to robot\(s\) \['r9'\]"):
        calibrate_render(CONFIG, ("r1", "r9"))
    assert calibrate_render(CONFIG, ("r1", "r2", "r3")).error_mm["max"] < 3.0


@pytest.mark.integration  # `vsfleet tracker calibrate --source render` runs as a child
def test_vsfleet_run_starts_the_scenarios_tracker_unless_told_otherwise(tmp_path):
    cam = load_scenario(CAMERA_SCENARIO)
    assert cam.tracker.kind == "camera"
    args = tracker_args(cam, str(CAMERA_SCENARIO), None, None, tmp_path)
    assert args[0] == "camera" and args[args.index("--source") + 1] == "render"
    assert Path(args[args.index("--camera") + 1]) == DEFAULT_CAMERA  # the scenario's, relative to its file
    assert args[args.index("--rate") + 1] == "30.0"
    sim = load_scenario(SIM_SCENARIO)
    assert tracker_args(sim, str(SIM_SCENARIO), None, None, tmp_path)[0] == "sim"
    forced = tracker_args(sim, str(SIM_SCENARIO), "camera", None, tmp_path)
    assert forced[0] == "camera" and (tmp_path / "calibration.json").exists()
    assert tracker_args(cam, str(CAMERA_SCENARIO), "sim", None, tmp_path)[0] == "sim"


def test_a_camera_tracker_section_refuses_the_simulated_trackers_keys_and_a_stray_camera():
    raw = {"schema": 1, "robots": {"r1": {"p": [0.0, 0.0]}}, "mission": {"goal": {"x": 1, "y": 0, "th": 0},
                                                                       "speed_max": 0.1, "turn_rate_max": 0.3}}
    ok = scenario_from_dict({**raw, "tracker": {"kind": "camera", "camera": "cam.toml", "rate_hz": 15}})
    assert dataclasses.astuple(ok.tracker)[-2:] == ("camera", "cam.toml")
    for tracker, words in (({"kind": "camera", "noise_xy_m": 0.001}, "noise_xy_m"),
                           ({"camera": "cam.toml"}, "kind = \"camera\""),
                           ({"kind": "lidar"}, "kind must be one of")):
        with pytest.raises(ScenarioError, match=words):
            scenario_from_dict({**raw, "tracker": tracker})


def test_a_calibration_or_intrinsics_file_with_a_misspelt_key_is_refused_with_the_key_named(
        tmp_path, calibration, renderer):
    from vsfleet.tracker.calib import CalibrationError, Intrinsics

    doc = calibration.to_dict()
    assert FloorCalibration.load(_write(tmp_path / "ok.json", doc)).model == doc["model"]
    # an optional key, misspelt: without the check its value would silently be the default
    optional = "plane_z" if doc["model"] == "homography" else "reprojection_error"
    with pytest.raises(CalibrationError, match=f"unknown field.*'{optional}'"):
        FloorCalibration.load(_write(tmp_path / "bad.json", {**doc, optional: 0.1}))
    intr = renderer.camera.intrinsics.to_dict()
    assert Intrinsics.load(_write(tmp_path / "intr.json", intr)).width_px == 1280
    with pytest.raises(CalibrationError, match="unknown field.*'dist_coefs'"):
        Intrinsics.load(_write(tmp_path / "intr-bad.json", {**intr, "dist_coefs": [0.1, 0, 0, 0]}))


def _write(path: Path, doc: dict) -> Path:
    import json

    path.write_text(json.dumps(doc))
    return path
