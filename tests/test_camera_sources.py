"""Camera sources: which are live, capture times with an injected clock, corrupt and unreadable videos,
--fps/--latency/--live, the periodic stats, and the synthetic RenderSource."""

from __future__ import annotations

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
from vsfleet.tracker import camera as camera_cmd  # noqa: E402
from vsfleet.tracker.camera import (  # noqa: E402
    BrokenVideo,
    CameraOpenError,
    EndOfVideo,
    FrameReadError,
    RenderSource,
    VideoSource,
    build_parser,
    check_source_args,
    is_live,
    run_loop,
    source_kind,
)
from vsfleet.tracker.markers import CameraTracker, ConfigError  # noqa: E402
from vsfleet.tracker.render import TruthBook, robot_scene, write_video  # noqa: E402
from vsfleet.wire import TruthMsg  # noqa: E402


@pytest.fixture(scope="module")
def frame_pair(config, renderer):
    return [renderer.render(robot_scene(config, renderer.spec, TRUTH), k / 10) for k in range(2)]


@pytest.fixture(scope="module")
def clip(tmp_path_factory, config, renderer):
    """A 10-frame FFV1 video of the robots moving 1 cm per frame along x, and a copy cut in half."""
    d = tmp_path_factory.mktemp("clips")
    path = d / "clip.avi"
    writer = write_video(path, 10.0, (renderer.spec.width_px, renderer.spec.height_px))
    for k in range(10):
        poses = {r: (x + 0.01 * k, y, th) for r, (x, y, th) in TRUTH.items()}
        writer.write(renderer.render(robot_scene(config, renderer.spec, poses), k / 10))
    writer.release()
    cut = d / "cut.avi"
    data = path.read_bytes()
    cut.write_bytes(data[: len(data) // 2])
    return path, cut


class FakeClock:
    def __init__(self, t0: float, step: float = 0.0) -> None:
        self.t, self.step = t0, step

    def __call__(self) -> float:
        t = self.t
        self.t += self.step
        return t


class FakeCapture:
    """cv2.VideoCapture's surface: frames to grab/read, a frame rate and count, and what was set."""

    def __init__(self, frames, fps=0.0, frame_count=-1.0, opened=True, buffersize_ok=True):
        self.frames = list(frames)
        self.fps, self.frame_count, self.opened, self.buffersize_ok = fps, frame_count, opened, buffersize_ok
        self.props = {}
        self.current = None
        self.released = False

    def isOpened(self):  # noqa: N802 - OpenCV's name
        return self.opened

    def set(self, prop, value):
        self.props[prop] = value
        return self.buffersize_ok

    def get(self, prop):
        return {cv2.CAP_PROP_FPS: self.fps, cv2.CAP_PROP_FRAME_COUNT: self.frame_count}.get(prop, 0.0)

    def grab(self):
        if not self.frames:
            return False
        self.current = self.frames.pop(0)
        return True

    def retrieve(self):
        return self.current is not None, self.current

    def read(self):
        return (True, self.frames.pop(0)) if self.frames else (False, None)

    def release(self):
        self.released = True


def never_wait(t_s):
    raise AssertionError(f"a live source is not paced (asked to wait until {t_s})")


# ---------------------------------------------------------------- what is live


@pytest.mark.parametrize("spec, kind", [
    ("0", "index"), ("12", "index"),
    ("/dev/video0", "device"), ("/dev/v4l/by-id/usb-046d_HD_Pro_Webcam_C920-video-index0", "device"),
    ("rtsp://10.0.0.5:554/stream1", "url"), ("file:///var/clips/run.avi", "url"),
    ("v4l2src device=/dev/video0 ! videoconvert ! appsink", "pipeline"),
    ("clip.avi", "file"), ("/data/run.mkv", "file"), ("render", "render"),
])
def test_source_kinds_and_which_are_live(spec, kind):
    assert source_kind(spec) == kind
    assert is_live(spec) == (kind != "file")
    assert is_live(spec, force=True)


def test_a_device_path_is_a_live_camera_with_one_buffered_frame_and_grab_times(frame_pair):
    cap = FakeCapture(frame_pair)
    clock = FakeClock(1000.0, 0.5)
    source = VideoSource("/dev/video0", clock=clock, wait_until=never_wait, latency_s=0.03,
                         capture=lambda spec: cap)
    assert source.live and cap.props == {cv2.CAP_PROP_BUFFERSIZE: 1}
    times = [source.read()[1] for _ in range(2)]
    assert times == pytest.approx([1000.0 - 0.03, 1000.5 - 0.03])  # the clock at grab, minus the latency
    with pytest.raises(FrameReadError, match="disconnected"):  # a camera that stops is a disconnect, not an end
        source.read()


def test_a_live_source_that_ignores_the_buffer_size_still_works_and_says_so(frame_pair, caplog):
    cap = FakeCapture(frame_pair, buffersize_ok=False)
    with caplog.at_level(logging.INFO):
        source = VideoSource("rtsp://cam/1", clock=FakeClock(5.0), capture=lambda spec: cap)
    assert source.read()[1] == 5.0
    assert "keeps its own frame buffer" in caplog.text


def test_the_live_path_on_a_file_url_times_frames_by_the_clock_and_retries_at_the_end(
        clip, config, calibration, caplog):
    path, _ = clip
    clock = FakeClock(500.0, 0.25)
    stop = StopFlag(install_signals=False)
    opened = []

    def open_source():
        opened.append(VideoSource(f"file://{path}", clock=clock, wait_until=never_wait, latency_s=0.1))
        return opened[-1]

    published = []
    stats = run_loop(open_source, CameraTracker(config, calibration), lambda r, m: published.append((r, m)),
                     stop, retries=0)
    assert opened[0].live
    assert stats.frames == 10 and stats.gave_up and stats.exit_code == 1  # live: the end is a disconnect
    assert "gave no frame (disconnected?); giving up after 1 attempts" in caplog.text
    ts = sorted({m.t for _, m in published})
    assert ts == pytest.approx([500.0 + 0.25 * k - 0.1 for k in range(10)])  # not t0 + index / fps
    for r, m in published:
        k = round((m.t + 0.1 - 500.0) / 0.25)
        assert abs(m.x - (TRUTH[r][0] + 0.01 * k)) < 0.002


def test_live_forces_a_file_path_live(clip):
    path, _ = clip
    source = VideoSource(str(path), clock=FakeClock(7.0), wait_until=never_wait, live=True)
    assert source.live and source.read()[1] == 7.0
    source.close()


# ---------------------------------------------------------------- video files


def test_a_truncated_video_is_an_error_not_a_normal_end(clip, config, calibration, caplog):
    path, cut = clip
    source = VideoSource(str(cut), t0_s=0.0)
    assert source.frame_count == 10
    published = []
    stats = run_loop(lambda: source, CameraTracker(config, calibration), lambda r, m: published.append(m),
                     StopFlag(install_signals=False))
    assert 0 < stats.frames < 10 and stats.exit_code == 1 and not stats.gave_up
    assert f"stopped after {stats.frames} of its 10 frames: the file is truncated or corrupt" in caplog.text
    with caplog.at_level(logging.INFO):
        whole = VideoSource(str(path), t0_s=0.0)
        stats = run_loop(lambda: whole, CameraTracker(config, calibration), lambda r, m: None,
                         StopFlag(install_signals=False))
    assert stats.frames == 10 and stats.exit_code == 0
    assert "end of video" in caplog.text


def test_a_video_that_stops_early_raises_broken_video_and_one_without_a_count_just_ends(frame_pair):
    source = VideoSource("x.avi", t0_s=0.0, capture=lambda spec: FakeCapture(frame_pair, fps=10.0, frame_count=5))
    source.read(), source.read()
    with pytest.raises(BrokenVideo, match="stopped after 2 of its 5 frames"):
        source.read()
    source = VideoSource("x.avi", t0_s=0.0, capture=lambda spec: FakeCapture(frame_pair, fps=10.0))
    source.read(), source.read()
    with pytest.raises(EndOfVideo):
        source.read()


def test_a_video_without_a_frame_rate_needs_fps(frame_pair):
    with pytest.raises(CameraOpenError, match="has no frame rate; give --fps") as err:
        VideoSource("x.avi", capture=lambda spec: FakeCapture(frame_pair, fps=0.0))
    assert err.value.fatal
    source = VideoSource("x.avi", t0_s=100.0, fps=12.5, capture=lambda spec: FakeCapture(frame_pair, fps=0.0))
    assert [source.read()[1] for _ in range(2)] == pytest.approx([100.0, 100.08])
    assert build_parser().parse_args(["--camera", "c", "--calibration", "k", "--source", "x.avi",
                                      "--fps", "12.5"]).fps == 12.5


def test_a_video_file_that_cannot_be_opened_is_not_retried(config, calibration, caplog):
    calls = []

    def open_source():
        calls.append(1)
        raise CameraOpenError("cannot open video file 'junk.avi'", fatal=True)

    stats = run_loop(open_source, CameraTracker(config, calibration), lambda r, m: None,
                     StopFlag(install_signals=False), retries=2, first_backoff_s=0.001)
    assert calls == [1] and stats.exit_code == 2 and stats.retries == 0 and not stats.gave_up
    assert "retry" not in caplog.text


@pytest.mark.integration  # starts a child process (tests/conftest.py)
def test_the_command_refuses_an_unreadable_video_at_once_and_fails_a_truncated_one(tmp_path, clip, calibration):
    _, cut = clip
    cal = tmp_path / "cal.json"
    calibration.save(cal)
    junk = tmp_path / "junk.avi"
    junk.write_text("not a video\n")
    out = run_cli("tracker", "camera", "--camera", str(CONFIG), "--calibration", str(cal), "--source", str(junk),
                  "--no-multicast-scouting")
    assert out.returncode == 2, out.stderr
    assert "cannot open video file" in out.stderr and "retry" not in out.stderr and "Traceback" not in out.stderr
    out = run_cli("tracker", "camera", "--camera", str(CONFIG), "--calibration", str(cal), "--source", str(cut),
                  "--no-pace", "--t0", "0", "--mode", "peer", "--listen", "tcp/127.0.0.1:0",
                  "--no-multicast-scouting")
    assert out.returncode == 1, out.stderr
    assert "truncated or corrupt" in out.stderr and "frames/s end to end" in out.stderr


# ---------------------------------------------------------------- flags that do not fit the source


def parsed(*extra):
    return build_parser().parse_args(["--camera", "c.toml", "--calibration", "k.json", *extra])


@pytest.mark.parametrize("extra, message", [
    (["--source", "0", "--fps", "30"], "a live source"),
    (["--source", "/dev/video0", "--t0", "5"], "a live source"),
    (["--source", "render", "--latency", "0.05"], "render takes --rate"),
    (["--source", "render", "--live"], "render takes --rate"),
    (["--source", "0", "--latency", "-0.01"], "--latency must be >= 0"),
    (["--source", "0", "--latency", "nan"], "finite"),
    (["--source", "x.avi", "--fps", "0"], "--fps must be > 0"),
    (["--source", "nowhere.avi"], "no such video file"),
])
def test_flags_that_do_not_fit_the_source_are_refused(extra, message):
    with pytest.raises(ConfigError, match=message):
        check_source_args(parsed(*extra))


def test_latency_is_for_live_sources(clip):
    path, _ = clip
    with pytest.raises(ConfigError, match="--latency is for live sources"):
        check_source_args(parsed("--source", str(path), "--latency", "0.05"))
    assert check_source_args(parsed("--source", str(path), "--latency", "0.05", "--live")) is True
    assert check_source_args(parsed("--source", str(path), "--fps", "15")) is False
    assert check_source_args(parsed("--source", "/dev/video3", "--latency", "0.05")) is True


def test_a_gstreamer_pipeline_is_live_and_needs_a_gstreamer_opencv(monkeypatch):
    pipeline = "v4l2src device=/dev/video0 ! videoconvert ! appsink"
    monkeypatch.setattr(camera_cmd, "gstreamer_available", lambda: False)
    with pytest.raises(ConfigError, match="no GStreamer backend"):
        check_source_args(parsed("--source", pipeline))
    monkeypatch.setattr(camera_cmd, "gstreamer_available", lambda: True)
    assert check_source_args(parsed("--source", pipeline)) is True


# ---------------------------------------------------------------- stats


class Frames:
    def __init__(self, frames, stop):
        self.frames, self.stop = list(frames), stop

    def read(self):
        if not self.frames:
            self.stop.set()
            return None
        return self.frames.pop(0)

    def close(self):
        pass


def test_the_loop_logs_end_to_end_frames_per_second_periodically(config, calibration, frame_pair, caplog):
    stop = StopFlag(install_signals=False)
    perf = FakeClock(0.0, 0.25)  # every perf() call: +0.25 s
    source = Frames([(frame_pair[0], 1.0 + k) for k in range(6)], stop)
    with caplog.at_level(logging.INFO):
        stats = run_loop(lambda: source, CameraTracker(config, calibration), lambda r, m: None, stop, perf=perf,
                         stats_every_s=2.0)
    assert stats.frames == 6 and stats.wall_s > 0
    assert stats.fps == pytest.approx(stats.frames / stats.wall_s)
    reports = [r.getMessage() for r in caplog.records if "frames/s end to end" in r.getMessage()]
    assert len(reports) >= 2
    assert "6 frames in" in stats.summary() and f"= {stats.fps:.1f} frames/s end to end" in stats.summary()


# ---------------------------------------------------------------- the synthetic camera


def test_render_source_draws_the_newest_truth_at_its_time_once(config, renderer, calibration):
    clock = FakeClock(100.02)
    waited = []

    def wait_until(t_s):
        waited.append(t_s)
        clock.t = max(clock.t, t_s)

    book = TruthBook()
    stop = StopFlag(install_signals=False)
    source = RenderSource(book, renderer, config, rate_hz=50.0, stop=stop, clock=clock, wait_until=wait_until)
    assert source.read() is None  # no truth yet
    for r, (x, y, th) in TRUTH.items():
        book.offer(r, TruthMsg(t=100.0, x=x, y=y, th=th, vl=0.0, vr=0.0))
    image, t_s = source.read()
    assert t_s == 100.0 and image.shape == (720, 1280) and image.dtype == np.uint8
    out = dict(CameraTracker(config, calibration).process(image, t_s))
    assert set(out) == set(TRUTH)
    for r, m in out.items():
        assert abs(m.x - TRUTH[r][0]) < 0.002 and abs(m.y - TRUTH[r][1]) < 0.002
    assert source.read() is None and source.repeats == 1  # the truth has not advanced: no frame, no seq
    book.offer("r1", TruthMsg(t=100.06, x=0.5, y=0.0, th=0.0, vl=0.0, vr=0.0))
    image, t_s = source.read()
    assert t_s == 100.06
    assert waited == pytest.approx([100.02, 100.04, 100.06, 100.08])  # paced at 50 Hz on the injected clock
    clock.t = 100.5  # all truth older than 0.1 s: nothing to draw
    assert source.read() is None
