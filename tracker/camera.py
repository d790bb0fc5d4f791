"""vsfleet tracker camera: ArUco markers seen by an overhead camera, published as frames and robot poses.

``--source`` is a camera index (``0``), a device (``/dev/video0``,
``/dev/v4l/by-id/...``), a stream URL (``rtsp://...``), a GStreamer pipeline
ending in ``appsink`` (needs an OpenCV built with GStreamer), a video file, or
``render`` (the synthetic camera of tracker.render, drawing the fleet's truth
in-process). Every frame gets one ``seq`` and is published as one message on
``vs/<fleet>/frame/<src>`` (every robot seen in it; the agents' input), and each
robot's pose on ``pose/<robot>`` (for tools). Every pose carries this tracker's
``src`` and ``t`` = the frame's capture time: for live sources (all but a video
file, or any source with ``--live``) the wall clock when ``grab()`` returns
minus ``--latency``; ``t0 + index / fps`` for a video file; the truth time
drawn for ``render``. A live source that fails to open or stops delivering
frames is retried with backoff; nothing is published meanwhile. A video file
that cannot be opened is an error at once (exit 2); one that ends before its
frame count is corrupt (exit 1).
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Protocol

import cv2
import numpy as np

from vsfleet.zglue.lifecycle import StopFlag, pace, wall_clock
from vsfleet.zglue.program import common_flags, program, refusing
from vsfleet.wire import FrameMsg, PoseMsg

from .calib import CalibrationError, FloorCalibration
from .markers import CameraConfig, CameraTracker, ConfigError, FrameError, load_config
from .render import Renderer, TruthBook, robot_scene, sim_camera_from_dict
from .sources import (  # noqa: F401 (IMAGE_SUFFIXES and gstreamer_available: re-exported)
    IMAGE_SUFFIXES,
    CameraOpenError,
    gstreamer_available,
    is_live,
    open_capture,
    quiet_opencv,
    source_kind,
)

log = logging.getLogger("vsfleet.tracker.camera")

TRUTH_MAX_AGE_S = 0.1
STATS_EVERY_S = 10.0



class FrameReadError(RuntimeError):
    """A live source gave no frame or an unreadable one (a disconnect, usually): reopen and retry."""


class EndOfVideo(Exception):
    """A video file has no more frames."""


class BrokenVideo(RuntimeError):
    """A video file that stops before its frame count, or gives an unreadable frame: truncated or corrupt."""


class Source(Protocol):
    def read(self) -> tuple[np.ndarray, float] | None: ...  # (frame, capture time [s]); None: no frame now
    def close(self) -> None: ...


class VideoSource:
    """cv2.VideoCapture on a camera index, a device, a stream URL, a pipeline or a video file.

    Live (``live``, default ``is_live(spec)``): the capture keeps one buffered
    frame (CAP_PROP_BUFFERSIZE = 1, where the backend honours it) and
    ``t`` = clock when ``grab()`` returns - ``latency_s``. File: ``t`` =
    t0 + index / fps, paced to the clock by ``wait_until`` (None: as fast as
    possible); a file that ends before its CAP_PROP_FRAME_COUNT raises BrokenVideo.
    ``capture`` opens the cv2.VideoCapture (a test passes a fake).
    """

    def __init__(self, spec: str, clock: Callable[[], float] = wall_clock, t0_s: float | None = None,
                 wait_until: Callable[[float], None] | None = None, fps: float | None = None,
                 live: bool | None = None, latency_s: float = 0.0,
                 capture: Callable[[str], cv2.VideoCapture] = open_capture) -> None:
        self.spec = spec
        self.live = is_live(spec) if live is None else live
        self.clock = clock
        self.wait_until = wait_until
        self.latency_s = latency_s
        self.index = 0
        self.frame_count: int | None = None
        self.cap = capture(spec)
        if not self.cap.isOpened():
            self.cap.release()
            if self.live:
                raise CameraOpenError(f"cannot open camera source {spec!r}")
            raise CameraOpenError(f"cannot open video file {spec!r} (not a video OpenCV can decode, "
                                  "or truncated)", fatal=True)
        if self.live:
            if not self.cap.set(cv2.CAP_PROP_BUFFERSIZE, 1):
                log.info("camera source %r keeps its own frame buffer (CAP_PROP_BUFFERSIZE not supported): "
                         "if processing falls behind, t lags the capture", spec)
            self.fps = fps
        else:
            self.fps = fps or self.cap.get(cv2.CAP_PROP_FPS)
            if not (self.fps and self.fps > 0 and math.isfinite(self.fps)):
                self.cap.release()
                raise CameraOpenError(f"video {spec!r} has no frame rate; give --fps", fatal=True)
            n = self.cap.get(cv2.CAP_PROP_FRAME_COUNT)
            self.frame_count = int(n) if n and n > 0 and math.isfinite(n) else None
        self.t0_s = None if self.live else clock() if t0_s is None else t0_s

    def read(self) -> tuple[np.ndarray, float]:
        if self.live:
            if not self.cap.grab():
                raise FrameReadError(f"camera {self.spec!r} gave no frame (disconnected?)")
            t_s = self.clock() - self.latency_s
            ok, image = self.cap.retrieve()
            if not ok or image is None or image.size == 0:
                raise FrameReadError(f"camera {self.spec!r} gave an unreadable frame")
            return image, t_s
        t_s = self.t0_s + self.index / self.fps
        ok, image = self.cap.read()
        if not ok:
            if self.frame_count is not None and self.index < self.frame_count:
                raise BrokenVideo(f"video {self.spec!r} stopped after {self.index} of its {self.frame_count} "
                                  "frames: the file is truncated or corrupt")
            raise EndOfVideo(f"end of video {self.spec!r} after {self.index} frames")
        if image is None or image.size == 0:
            raise BrokenVideo(f"video {self.spec!r}: frame {self.index} is unreadable (corrupt file)")
        self.index += 1
        if self.wait_until is not None:
            self.wait_until(t_s)
        return image, t_s

    def close(self) -> None:
        self.cap.release()


class RenderSource:
    """The synthetic camera: the latest truth drawn at ``rate_hz``; ``t`` = the truth time drawn.

    A tick whose newest truth is no newer than the last frame's gives no frame
    (so no two frames share a ``t``); ``repeats`` counts them.
    """

    def __init__(self, book: TruthBook, renderer: Renderer, config: CameraConfig, rate_hz: float,
                 stop: StopFlag, clock: Callable[[], float] = wall_clock,
                 wait_until: Callable[[float], None] | None = None) -> None:
        self.book, self.renderer, self.config = book, renderer, config
        self.period_s = 1.0 / rate_hz
        self.stop, self.clock = stop, clock
        self.wait_until = wait_until or (lambda t_s: pace(t_s, stop, clock))
        self.next_s = clock()
        self.last_t: float | None = None
        self.repeats = 0

    def read(self) -> tuple[np.ndarray, float] | None:
        self.wait_until(self.next_s)
        now = self.clock()
        self.next_s = max(self.next_s + self.period_s, now)  # fell behind: skip frames rather than burst
        got = self.book.fresh(now, TRUTH_MAX_AGE_S)
        if got is None:
            return None
        t_s, poses = got
        if self.last_t is not None and t_s <= self.last_t:
            self.repeats += 1
            return None
        self.last_t = t_s
        scene = robot_scene(self.config, self.renderer.spec, poses)
        return self.renderer.render(scene, t_s), t_s

    def close(self) -> None:
        pass


@dataclass
class LoopStats:
    frames: int = 0
    poses: int = 0
    bad_frames: int = 0
    retries: int = 0
    process_s: float = 0.0   # time spent in CameraTracker.process (detection and projection)
    wall_s: float = 0.0      # from the source's first open to the last frame published (perf clock)
    gave_up: bool = False
    exit_code: int = 0       # 1: gave up, or a corrupt video; 2: a video file that cannot be opened

    @property
    def fps(self) -> float:
        """End to end: frames read, detected and published per second of wall time."""
        return self.frames / self.wall_s if self.wall_s > 0 else 0.0

    def summary(self) -> str:
        per_frame = f"{1000 * self.process_s / self.frames:.1f} ms" if self.frames else "-"
        return (f"{self.frames} frames in {self.wall_s:.1f} s = {self.fps:.1f} frames/s end to end "
                f"(read + detect + publish; detection {per_frame} per frame), {self.poses} poses, "
                f"{self.bad_frames} bad frames, {self.retries} retries")


def frame_of(src: str, seq: int, t_s: float, poses: list[tuple[str, PoseMsg]]) -> FrameMsg:
    """One camera frame as the frame message: every robot seen, (x, y, th) [m, rad; world] at t_s [s]."""
    return FrameMsg(t=float(t_s), seq=seq, src=src, poses={robot: (m.x, m.y, m.th) for robot, m in poses})


def backoff_s(attempt: int, first_s: float = 0.5, max_s: float = 8.0) -> float:
    return min(max_s, first_s * 2 ** (attempt - 1))


def run_loop(open_source: Callable[[], Source], tracker: CameraTracker,
             publish: Callable[[str, PoseMsg], None], stop: StopFlag, retries: int = -1,
             first_backoff_s: float = 0.5, perf: Callable[[], float] = time.perf_counter,
             stats_every_s: float = STATS_EVERY_S,
             publish_frame: Callable[[FrameMsg], None] | None = None) -> LoopStats:
    """Read, detect, publish until stop, the end of a video, or ``retries`` failed attempts in a row (-1: never).

    Every frame detected gives one ``publish_frame`` (also with no robot seen), then
    one ``publish`` per robot seen.

    A live source that fails to open or to give a frame is closed and reopened
    after a logged backoff; an unusable frame is counted and skipped. A video
    file that cannot be opened (exit code 2) or is corrupt (exit code 1) ends
    the loop at once. Every ``stats_every_s`` of ``perf`` time the stats are logged.
    """
    stats = LoopStats()
    source: Source | None = None
    failures = 0
    started: float | None = None
    next_report = perf() + stats_every_s

    def failed(exc: Exception) -> bool:
        nonlocal failures
        failures += 1
        if 0 <= retries < failures:
            log.error("%s; giving up after %d attempts", exc, failures)
            stats.gave_up = True
            stats.exit_code = 1
            return True
        delay = backoff_s(failures, first_backoff_s)
        stats.retries += 1
        log.warning("%s; retry %d in %.1f s", exc, failures, delay)
        stop.wait(delay)
        return False

    try:
        while not stop.is_set():
            if source is None:
                try:
                    source = open_source()
                except CameraOpenError as exc:
                    if exc.fatal:
                        log.error("%s", exc)
                        stats.exit_code = 2
                        break
                    if failed(exc):
                        break
                    continue
                log.info("camera source open")
                if started is None:
                    started = perf()
            try:
                got = source.read()
            except EndOfVideo as exc:
                log.info("%s", exc)
                break
            except BrokenVideo as exc:
                log.error("%s", exc)
                stats.exit_code = 1
                break
            except FrameReadError as exc:
                source.close()
                source = None
                if failed(exc):
                    break
                continue
            if got is not None:
                image, t_s = got
                start = perf()
                try:
                    poses = tracker.process(image, t_s)
                except FrameError as exc:
                    stats.bad_frames += 1
                    tracker.rejections.reject(f"camera/{tracker.src}/frame/bad", str(exc))
                    poses = None
                if poses is not None:
                    stats.process_s += perf() - start
                    stats.frames += 1
                    failures = 0
                    if publish_frame is not None:
                        publish_frame(frame_of(tracker.src, tracker.seq, t_s, poses))
                    for robot, msg in poses:
                        publish(robot, msg)
                        stats.poses += 1
                    stats.wall_s = perf() - started
            now = perf()
            if now >= next_report:
                next_report = now + stats_every_s
                log.info("camera tracker %s: %s, %d rejected", tracker.src, stats.summary(),
                         tracker.rejections.count)
    finally:
        if source is not None:
            source.close()
    return stats


def video_t0(spec: str, t0_s: float | None) -> float | None:
    """The capture time of a video's frame 0: ``t0_s``, else its ``<video>.json`` sidecar, else None."""
    if t0_s is not None or is_live(spec):
        return t0_s
    sidecar = Path(spec + ".json")
    if not sidecar.exists():
        return None
    try:
        t0 = json.loads(sidecar.read_text()).get("t0_s")
    except (OSError, ValueError, AttributeError):
        raise ConfigError(f"{sidecar}: not a video sidecar (JSON with 't0_s')") from None
    if not isinstance(t0, (int, float)) or isinstance(t0, bool):
        raise ConfigError(f"{sidecar}: 't0_s' must be a number")
    return float(t0)


def run_camera_tracker(conf, config: CameraConfig, calibration: FloorCalibration, source: str,
                       fleet: str = "demo", src: str | None = None, rate_hz: float = 30.0,
                       t0_s: float | None = None, paced: bool = True, retries: int = -1,
                       stop: StopFlag | None = None, clock: Callable[[], float] = wall_clock,
                       fps: float | None = None, live: bool | None = None, latency_s: float = 0.0) -> LoopStats:
    """The zenoh adapter: frames on vs/<fleet>/frame/<src>, poses on vs/<fleet>/pose/<robot>,
    liveliness vs/<fleet>/alive/tracker/<src>."""
    import zenoh

    from vsfleet.zglue.zconf import BURST_QOS, STREAM_QOS
    from vsfleet.wire import Keys, decode_truth, encode, encode_frame

    stop = stop or StopFlag()
    keys = Keys(fleet)
    tracker = CameraTracker(config, calibration, src)
    from vsfleet.zglue.zconf import open_session

    with open_session(conf) as session:
        pubs: dict[str, zenoh.Publisher] = {}
        token = session.liveliness().declare_token(keys.alive("tracker", tracker.src))
        frame_pub = session.declare_publisher(keys.frame(tracker.src), **STREAM_QOS)
        subs = []

        def publish_frame(msg: FrameMsg) -> None:
            frame_pub.put(encode_frame(msg))

        def publish(robot: str, msg: PoseMsg) -> None:
            if robot not in pubs:
                pubs[robot] = session.declare_publisher(keys.pose(robot), **BURST_QOS)
            pubs[robot].put(encode(msg))

        if source == "render":
            spec = sim_camera_from_dict(config.sim_camera)
            renderer = Renderer(spec, config.dictionary)
            book = TruthBook()

            def on_truth(sample: zenoh.Sample) -> None:
                key = str(sample.key_expr)
                try:
                    book.offer(keys.robot_of(key, "truth"), decode_truth(sample.payload.to_bytes()))
                except Exception as exc:  # noqa: BLE001 - WireError, or anything else: counted, never fatal
                    tracker.rejections.reject(key, str(exc))

            subs.append(session.declare_subscriber(keys.truth(), on_truth))

            def open_source() -> Source:
                return RenderSource(book, renderer, config, rate_hz, stop, clock)
        else:
            def wait_until(t_s: float) -> None:
                pace(t_s, stop, clock)

            def open_source() -> Source:
                return VideoSource(source, clock, t0_s, wait_until if paced else None, fps, live, latency_s)

        log.info("camera tracker %s up: source %s (%s), %d markers mapped", tracker.src, source,
                 "render" if source == "render" else "live" if is_live(source, bool(live)) else "video file",
                 len(config.markers))
        try:
            stats = run_loop(open_source, tracker, publish, stop, retries, publish_frame=publish_frame)
        finally:
            for s in subs:
                s.undeclare()
            token.undeclare()
    log.info("camera tracker %s stopping after %s, %d rejected", tracker.src, stats.summary(),
             tracker.rejections.count)
    return stats


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="vsfleet tracker camera", description=__doc__.splitlines()[0])
    p.add_argument("--camera", required=True, help="camera config TOML (src, dictionary, marker -> robot map)")
    p.add_argument("--calibration", required=True, help="floor calibration JSON from `vsfleet tracker calibrate`")
    p.add_argument("--source", required=True,
                   help="camera index (0), device (/dev/video0), stream URL, GStreamer pipeline ending in "
                        "'appsink', video file, or 'render' (synthetic camera over the truth)")
    p.add_argument("--fleet", default="demo")
    p.add_argument("--src", default=None, help="tracker id sent as 'src' (default: the config's)")
    p.add_argument("--live", action="store_true",
                   help="treat --source as live even if it looks like a file (t = grab time - latency, "
                        "a failed read is a disconnect, retried)")
    p.add_argument("--latency", type=float, default=0.0,
                   help="live sources: exposure-to-grab delay [s] subtracted from the grab time (default 0)")
    p.add_argument("--fps", type=float, default=None,
                   help="frame rate of a video file [Hz] (default: the file's own; needed if it has none)")
    p.add_argument("--rate", type=float, default=30.0, help="frame rate of --source render [Hz]")
    p.add_argument("--t0", type=float, default=None,
                   help="capture time of a video file's frame 0 [UNIX s] (default: its .json sidecar, else now)")
    p.add_argument("--no-pace", action="store_true", help="read a video file as fast as possible")
    p.add_argument("--retries", type=int, default=-1,
                   help="live sources: give up after this many failed opens/reads in a row (default: never)")
    return common_flags(p)


def check_source_args(args: argparse.Namespace) -> bool:
    """ConfigError for flags that do not fit ``--source``; returns whether the source is live."""
    for name in ("rate", "fps", "latency", "t0"):
        v = getattr(args, name)
        if v is not None and not math.isfinite(v):
            raise ConfigError(f"--{name} must be a finite number")
    if args.rate <= 0:
        raise ConfigError("--rate must be > 0")
    if args.fps is not None and args.fps <= 0:
        raise ConfigError("--fps must be > 0")
    if args.latency < 0:
        raise ConfigError("--latency must be >= 0")
    kind = source_kind(args.source)
    if kind == "render":
        if args.live or args.latency or args.fps is not None or args.t0 is not None:
            raise ConfigError("--source render takes --rate; --live, --latency, --fps and --t0 are for cameras "
                              "and video files (render frames carry the truth time)")
        return False
    live = is_live(args.source, args.live)
    if live and (args.fps is not None or args.t0 is not None):
        raise ConfigError(f"--fps and --t0 time a video file's frames; a live source ({kind}) is timed at grab "
                          "(use --latency)")
    if not live and args.latency:
        raise ConfigError("--latency is for live sources; a video file's frames are timed t0 + index / fps "
                          "(use --t0, or --live to read the file as a live source)")
    if kind == "pipeline" and not gstreamer_available():
        raise ConfigError("--source is a GStreamer pipeline, but this OpenCV has no GStreamer backend "
                          "(the opencv-python-headless wheels have none): give a camera index, a /dev/video* "
                          "device or a stream URL, or install an OpenCV built with GStreamer")
    if not live and not Path(args.source).exists():
        raise ConfigError(f"no such video file {args.source!r} (a camera is an index such as 0 or a /dev/video* "
                          "device, a stream a URL; --live reads a path as a live source)")
    return live


@program(build_parser, log)
def main(args: argparse.Namespace) -> int:
    from vsfleet.zglue.zconf import zenoh_config
    from vsfleet.wire import Keys, WireError, check_name

    quiet_opencv(args.verbose)
    with refusing(ConfigError, CalibrationError, WireError, CameraOpenError):
        Keys(args.fleet)
        if args.src is not None:
            check_name(args.src, "src")
        live = check_source_args(args)
        config = load_config(args.camera)
        calibration = FloorCalibration.load(args.calibration)
        if args.source == "render":
            spec = sim_camera_from_dict(config.sim_camera, f"{args.camera}: [sim_camera]")
            if (spec.width_px, spec.height_px) != (calibration.width_px, calibration.height_px):
                raise ConfigError(f"the sim camera is {spec.width_px}x{spec.height_px} px, the calibration is "
                                  f"for {calibration.width_px}x{calibration.height_px} px")
        t0 = video_t0(args.source, args.t0) if not live else None
        CameraTracker(config, calibration)  # a homography at the wrong height, a camera below: fail here
        if args.source != "render" and not live:
            VideoSource(args.source, t0_s=0.0, fps=args.fps, live=False).close()  # unreadable: fail now
    stats = run_camera_tracker(zenoh_config(args), config, calibration, args.source, args.fleet, args.src,
                               args.rate, t0, not args.no_pace, args.retries, fps=args.fps, live=live,
                               latency_s=args.latency)
    return stats.exit_code


if __name__ == "__main__":
    raise SystemExit(main())
