"""The camera tracker's edges: sources, retries with backoff, video files, and the command lines."""

from __future__ import annotations

import json
import logging

import numpy as np
import pytest

cv2 = pytest.importorskip("cv2")

from camera_support import (  # noqa: E402, F401 - the fixtures calibration, config, renderer
    CONFIG,
    TRUTH,
    calibration_fixture,
    config_fixture,
    renderer_fixture,
    run_cli,
)
from vsfleet.zglue.lifecycle import StopFlag  # noqa: E402
from vsfleet.tracker import calibrate as calibrate_cmd  # noqa: E402
from vsfleet.tracker import render as render_cmd  # noqa: E402
from vsfleet.tracker.calib import FloorCalibration  # noqa: E402
from vsfleet.tracker.camera import (  # noqa: E402
    CameraOpenError,
    EndOfVideo,
    FrameReadError,
    VideoSource,
    run_loop,
    video_t0,
)
from vsfleet.tracker.markers import CameraTracker  # noqa: E402
from vsfleet.tracker.render import robot_scene, write_video  # noqa: E402


@pytest.fixture(scope="module")
def frame(config, renderer):
    return renderer.render(robot_scene(config, renderer.spec, TRUTH), 0.0)


class ScriptedSource:
    """Plays a script of frames and failures; every open of the factory takes the next opener."""

    def __init__(self, steps, stop):
        self.steps = list(steps)
        self.stop = stop
        self.closed = False

    def read(self):
        if not self.steps:
            self.stop.set()
            return None
        step = self.steps.pop(0)
        if isinstance(step, Exception):
            raise step
        return step

    def close(self):
        self.closed = True


def factory(openers):
    opened = []

    def open_source():
        item = openers.pop(0)
        if isinstance(item, Exception):
            raise item
        opened.append(item)
        return item
    return open_source, opened


def test_a_camera_that_fails_to_open_is_retried_with_backoff_and_nothing_is_published(
        config, calibration, frame, caplog):
    stop = StopFlag(install_signals=False)
    good = ScriptedSource([(frame, 1.0), (frame, 1.1)], stop)
    open_source, _ = factory([CameraOpenError("cannot open camera source '0'"),
                              CameraOpenError("cannot open camera source '0'"), good])
    published = []
    tracker = CameraTracker(config, calibration)
    stats = run_loop(open_source, tracker, lambda r, m: published.append((r, m)), stop, first_backoff_s=0.001)
    assert stats.retries == 2 and stats.frames == 2 and not stats.gave_up
    assert "cannot open camera source '0'; retry 1 in" in caplog.text
    assert "retry 2 in" in caplog.text
    assert [m.seq for _, m in published] == [1, 1, 1, 2, 2, 2]
    assert good.closed


def test_a_disconnect_closes_and_reopens_the_source(config, calibration, frame, caplog):
    stop = StopFlag(install_signals=False)
    first = ScriptedSource([(frame, 1.0), FrameReadError("camera '0' gave no frame (disconnected?)")], stop)
    second = ScriptedSource([(frame, 2.0)], stop)
    open_source, opened = factory([first, second])
    published = []
    stats = run_loop(open_source, CameraTracker(config, calibration), lambda r, m: published.append(m),
                     stop, first_backoff_s=0.001)
    assert opened == [first, second] and first.closed and second.closed
    assert stats.frames == 2 and stats.retries == 1
    assert [m.t for m in published] == [1.0] * 3 + [2.0] * 3
    assert "disconnected?); retry 1" in caplog.text


def test_retries_run_out_after_the_given_count(config, calibration, caplog):
    stop = StopFlag(install_signals=False)
    open_source, _ = factory([CameraOpenError("cannot open camera source 'rtsp://x'")] * 5)
    with caplog.at_level(logging.INFO):
        stats = run_loop(open_source, CameraTracker(config, calibration), lambda r, m: None, stop,
                         retries=2, first_backoff_s=0.001)
    assert stats.gave_up and stats.retries == 2 and stats.frames == 0
    assert "giving up after 3 attempts" in caplog.text


def test_unusable_frames_are_counted_and_publish_nothing(config, calibration, frame, caplog):
    stop = StopFlag(install_signals=False)
    src = ScriptedSource([(np.zeros((10, 10), np.uint8), 1.0), (frame.astype(np.float32), 1.1), (frame, 1.2)], stop)
    open_source, _ = factory([src])
    published = []
    tracker = CameraTracker(config, calibration)
    stats = run_loop(open_source, tracker, lambda r, m: published.append(m), stop)
    assert stats.bad_frames == 2 and stats.frames == 1
    assert {m.seq for m in published} == {1} and {m.t for m in published} == {1.2}
    assert tracker.rejections.by_key == {"frame": 2}
    assert "frame is 10x10 px, the calibration is for 1280x720 px" in caplog.text


def test_a_video_file_gives_capture_times_from_t0_and_fps(tmp_path, config, renderer, calibration):
    path = tmp_path / "clip.avi"
    writer = write_video(path, 10.0, (renderer.spec.width_px, renderer.spec.height_px))
    for k in range(3):
        poses = {r: (x + 0.05 * k, y, th) for r, (x, y, th) in TRUTH.items()}
        writer.write(renderer.render(robot_scene(config, renderer.spec, poses), k / 10))
    writer.release()
    (tmp_path / "clip.avi.json").write_text(json.dumps({"t0_s": 1000.0, "fps": 10.0, "frames": 3}))
    t0 = video_t0(str(path), None)
    assert t0 == 1000.0 and video_t0(str(path), 5.0) == 5.0
    source = VideoSource(str(path), clock=lambda: 0.0, t0_s=t0)
    tracker = CameraTracker(config, calibration)
    times = []
    for k in range(3):
        image, t_s = source.read()
        times.append(t_s)
        out = dict(tracker.process(image, t_s))
        assert abs(out["r1"].x - (0.3 + 0.05 * k)) < 0.002
    with pytest.raises(EndOfVideo):
        source.read()
    source.close()
    assert times == pytest.approx([1000.0, 1000.1, 1000.2])


def test_a_missing_video_file_fails_to_open_for_good_a_missing_camera_is_retried():
    with pytest.raises(CameraOpenError, match="cannot open video file") as err:
        VideoSource("/nonexistent/clip.avi")
    assert err.value.fatal
    with pytest.raises(CameraOpenError, match="cannot open camera source") as err:
        VideoSource("/nonexistent/clip.avi", live=True)
    assert not err.value.fatal


def test_calibrate_command_writes_a_calibration_and_reports_mm(tmp_path, capsys):
    calib_png, intr, out = tmp_path / "calib.png", tmp_path / "intr.json", tmp_path / "cal.json"
    assert render_cmd.main(["--camera", str(CONFIG), "--calibration-image", str(calib_png),
                            "--write-intrinsics", str(intr)]) == 0
    assert calibrate_cmd.main(["--camera", str(CONFIG), "--source", str(calib_png), "--intrinsics", str(intr),
                               "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "pinhole calibration from 6 reference markers" in text
    assert "reprojection error on the floor: mean" in text and " mm" in text
    cal = FloorCalibration.load(out)
    assert cal.model == "pinhole" and cal.error_mm["max"] < 3.0


@pytest.mark.integration  # starts a child process (tests/conftest.py)
def test_camera_command_refuses_a_missing_or_malformed_calibration_without_a_trace(tmp_path):
    missing = run_cli("tracker", "camera", "--camera", str(CONFIG), "--calibration", str(tmp_path / "no.json"),
                      "--source", "0", "--no-multicast-scouting")
    assert missing.returncode == 2
    assert "cannot read calibration file" in missing.stderr and "Traceback" not in missing.stderr
    bad = tmp_path / "bad.json"
    bad.write_text('{"format": "vsfleet-floor-calibration", "model": "homography"}')
    out = run_cli("tracker", "calibrate", "--camera", str(CONFIG), "--source", str(tmp_path / "no.png"),
                  "--out", str(bad))
    assert out.returncode == 2 and "no such image or video file" in out.stderr and "Traceback" not in out.stderr
    malformed = run_cli("tracker", "camera", "--camera", str(CONFIG), "--calibration", str(bad),
                        "--source", "0", "--no-multicast-scouting")
    assert malformed.returncode == 2
    assert "image_size_px" in malformed.stderr and "Traceback" not in malformed.stderr


@pytest.mark.integration  # starts a child process (tests/conftest.py)
def test_camera_command_refuses_a_malformed_config_and_a_missing_video(tmp_path, calibration):
    cal = tmp_path / "cal.json"
    calibration.save(cal)
    bad = tmp_path / "cam.toml"
    bad.write_text('src = "cam1"\ndictionary = "DICT_4X4_50"\n[markers]\n1 = "r1"\n2 = "r1"\n')
    out = run_cli("tracker", "camera", "--camera", str(bad), "--calibration", str(cal), "--source", "0",
                  "--no-multicast-scouting")
    assert out.returncode == 2 and "more than one marker" in out.stderr and "Traceback" not in out.stderr
    out = run_cli("tracker", "camera", "--camera", str(CONFIG), "--calibration", str(cal),
                  "--source", str(tmp_path / "none.avi"), "--no-multicast-scouting")
    assert out.returncode == 2 and "no such video file" in out.stderr and "Traceback" not in out.stderr


@pytest.mark.integration  # starts a child process (tests/conftest.py)
def test_camera_command_retries_a_camera_that_does_not_open_then_gives_up(calibration, tmp_path):
    cal = tmp_path / "cal.json"
    calibration.save(cal)
    out = run_cli("tracker", "camera", "--camera", str(CONFIG), "--calibration", str(cal), "--source", "7",
                  "--retries", "1", "--mode", "peer", "--listen", "tcp/127.0.0.1:0", "--no-multicast-scouting")
    assert out.returncode == 1, out.stderr
    assert "cannot open camera source '7'; retry 1 in 0.5 s" in out.stderr
    assert "giving up after 2 attempts" in out.stderr and "0 poses" in out.stderr
    assert "Traceback" not in out.stderr and "[ WARN" not in out.stderr  # OpenCV's own noise is off


def test_render_writes_a_video_whose_frames_the_tracker_reads_at_their_capture_times(
        tmp_path, config, renderer, calibration):
    from vsfleet.tracker.render import TruthBook, record_video
    from vsfleet.wire import TruthMsg

    book = TruthBook()
    for r, (x, y, th) in TRUTH.items():
        book.offer(r, TruthMsg(t=100.0, x=x, y=y, th=th, vl=0.0, vr=0.0))
    out = tmp_path / "run.avi"
    stop = StopFlag(install_signals=False)
    frames = record_video(book, renderer, config, out, fps=50.0, duration_s=0.1, stop=stop, clock=lambda: 100.0)
    assert frames == 5
    assert json.loads((tmp_path / "run.avi.json").read_text()) == {"t0_s": 100.0, "fps": 50.0, "frames": 5}
    source = VideoSource(str(out), t0_s=video_t0(str(out), None))
    tracker = CameraTracker(config, calibration)
    published = []
    stats = run_loop(lambda: source, tracker, lambda r, m: published.append((r, m)), stop)
    assert stats.frames == 5 and not stats.gave_up
    assert sorted({m.t for _, m in published}) == pytest.approx([100.0, 100.02, 100.04, 100.06, 100.08])
    for r, m in published:
        assert abs(m.x - TRUTH[r][0]) < 0.002 and abs(m.y - TRUTH[r][1]) < 0.002
