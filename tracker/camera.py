"""vsfleet tracker camera: ArUco markers seen by an overhead camera, published as robot poses.

``--source`` is a camera index, a video file, a stream URL (anything
cv2.VideoCapture opens) or ``render`` (the synthetic camera of tracker.render,
drawing the fleet's truth in-process). Every frame gets one ``seq``; every pose
carries this tracker's ``src`` and ``t`` = the frame's capture time: the wall
clock at grab for live sources, ``t0 + index / fps`` for a video file, the
truth time drawn for ``render``. A camera that fails to open or stops
delivering frames is retried with backoff; nothing is published meanwhile.
"""

from __future__ import annotations

import argparse
import json
import logging
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Protocol

import cv2
import numpy as np

from fleetctl.lifecycle import StopFlag, pace, wall_clock
from vsfleet.wire import PoseMsg

from .calib import CalibrationError, FloorCalibration
from .markers import CameraConfig, CameraTracker, ConfigError, FrameError, load_config
from .render import Renderer, TruthBook, robot_scene, sim_camera_from_dict

log = logging.getLogger("vsfleet.tracker.camera")

TRUTH_MAX_AGE_S = 0.1
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".pgm", ".ppm")


class CameraOpenError(RuntimeError):
    """The camera, file or stream cannot be opened."""


class FrameReadError(RuntimeError):
    """The source gave no frame or an unreadable one (a disconnect, usually)."""


class EndOfVideo(Exception):
    """A video file has no more frames."""


class Source(Protocol):
    def read(self) -> tuple[np.ndarray, float] | None: ...  # (frame, capture time [s]); None: no frame now
    def close(self) -> None: ...


def is_live(spec: str) -> bool:
    return spec.isdigit() or "://" in spec


class VideoSource:
    """cv2.VideoCapture on a camera index, a stream URL or a video file.

    Live: ``t`` = clock at grab. File: ``t`` = t0 + index / fps, paced to the
    clock by ``wait_until`` (pass None to read as fast as possible).
    """

    def __init__(self, spec: str, clock: Callable[[], float] = wall_clock, t0_s: float | None = None,
                 wait_until: Callable[[float], None] | None = None, fps: float | None = None) -> None:
        self.spec = spec
        self.live = is_live(spec)
        self.clock = clock
        self.wait_until = wait_until
        self.index = 0
        self.cap = cv2.VideoCapture(int(spec) if spec.isdigit() else spec)
        if not self.cap.isOpened():
            self.cap.release()
            raise CameraOpenError(f"cannot open camera source {spec!r}")
        self.fps = fps or self.cap.get(cv2.CAP_PROP_FPS)
        if not self.live and not (self.fps and self.fps > 0):
            self.cap.release()
            raise CameraOpenError(f"video {spec!r} has no frame rate; give --fps")
        self.t0_s = clock() if t0_s is None else t0_s

    def read(self) -> tuple[np.ndarray, float]:
        if self.live:
            if not self.cap.grab():
                raise FrameReadError(f"camera {self.spec!r} gave no frame (disconnected?)")
            t_s = self.clock()
            ok, image = self.cap.retrieve()
        else:
            t_s = self.t0_s + self.index / self.fps
            ok, image = self.cap.read()
            if not ok:
                raise EndOfVideo(f"end of video {self.spec!r} after {self.index} frames")
            self.index += 1
            if self.wait_until is not None:
                self.wait_until(t_s)
        if not ok or image is None or image.size == 0:
            raise FrameReadError(f"camera {self.spec!r} gave an unreadable frame")
        return image, t_s

    def close(self) -> None:
        self.cap.release()


class RenderSource:
    """The synthetic camera: the latest truth drawn at ``rate_hz``; ``t`` = the truth time drawn."""

    def __init__(self, book: TruthBook, renderer: Renderer, config: CameraConfig, rate_hz: float,
                 stop: StopFlag, clock: Callable[[], float] = wall_clock) -> None:
        self.book, self.renderer, self.config = book, renderer, config
        self.period_s = 1.0 / rate_hz
        self.stop, self.clock = stop, clock
        self.next_s = clock()

    def read(self) -> tuple[np.ndarray, float] | None:
        pace(self.next_s, self.stop, self.clock)
        now = self.clock()
        self.next_s = max(self.next_s + self.period_s, now)  # fell behind: skip frames rather than burst
        got = self.book.fresh(now, TRUTH_MAX_AGE_S)
        if got is None:
            return None
        t_s, poses = got
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
    gave_up: bool = False


def backoff_s(attempt: int, first_s: float = 0.5, max_s: float = 8.0) -> float:
    return min(max_s, first_s * 2 ** (attempt - 1))


def run_loop(open_source: Callable[[], Source], tracker: CameraTracker,
             publish: Callable[[str, PoseMsg], None], stop: StopFlag, retries: int = -1,
             first_backoff_s: float = 0.5, perf: Callable[[], float] = time.perf_counter) -> LoopStats:
    """Read, detect, publish until stop, the end of a video, or ``retries`` failed attempts in a row (-1: never).

    A source that fails to open or to give a frame is closed and reopened after
    a logged backoff; an unusable frame is counted and skipped.
    """
    stats = LoopStats()
    source: Source | None = None
    failures = 0

    def failed(exc: Exception) -> bool:
        nonlocal failures
        failures += 1
        if 0 <= retries < failures:
            log.error("%s; giving up after %d attempts", exc, failures)
            stats.gave_up = True
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
                    if failed(exc):
                        break
                    continue
                log.info("camera source open")
            try:
                got = source.read()
            except EndOfVideo as exc:
                log.info("%s", exc)
                break
            except FrameReadError as exc:
                source.close()
                source = None
                if failed(exc):
                    break
                continue
            if got is None:
                continue
            image, t_s = got
            start = perf()
            try:
                poses = tracker.process(image, t_s)
            except FrameError as exc:
                stats.bad_frames += 1
                tracker.rejections.reject(f"camera/{tracker.src}/frame/bad", str(exc))
                continue
            stats.process_s += perf() - start
            stats.frames += 1
            failures = 0
            for robot, msg in poses:
                publish(robot, msg)
                stats.poses += 1
    finally:
        if source is not None:
            source.close()
    return stats


def quiet_opencv(verbose: bool) -> None:
    """OpenCV's own warnings (a camera that does not open, ...) only with --verbose; ours say it once."""
    if not verbose:
        cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_ERROR)


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
                       stop: StopFlag | None = None, clock: Callable[[], float] = wall_clock) -> LoopStats:
    """The zenoh adapter: poses on vs/<fleet>/pose/<robot>, liveliness vs/<fleet>/alive/tracker/<src>."""
    import zenoh

    from fleetctl.zconf import STREAM_QOS
    from vsfleet.wire import Keys, decode_truth, encode

    stop = stop or StopFlag()
    keys = Keys(fleet)
    tracker = CameraTracker(config, calibration, src)
    with zenoh.open(conf) as session:
        pubs: dict[str, zenoh.Publisher] = {}
        token = session.liveliness().declare_token(keys.alive("tracker", tracker.src))
        subs = []

        def publish(robot: str, msg: PoseMsg) -> None:
            if robot not in pubs:
                pubs[robot] = session.declare_publisher(keys.pose(robot), **STREAM_QOS)
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
                return VideoSource(source, clock, t0_s, wait_until if paced else None)

        log.info("camera tracker %s up: source %s, %d markers mapped", tracker.src, source, len(config.markers))
        try:
            stats = run_loop(open_source, tracker, publish, stop, retries)
        finally:
            for s in subs:
                s.undeclare()
            token.undeclare()
    per_frame = f"{1000 * stats.process_s / stats.frames:.1f} ms" if stats.frames else "-"
    log.info("camera tracker stopping after %d frames (%s detection per frame), %d poses, "
             "%d bad frames, %d retries, %d rejected", stats.frames, per_frame, stats.poses,
             stats.bad_frames, stats.retries, tracker.rejections.count)
    return stats


def build_parser() -> argparse.ArgumentParser:
    from fleetctl.zconf import add_zenoh_args

    p = argparse.ArgumentParser(prog="vsfleet tracker camera", description=__doc__.splitlines()[0])
    p.add_argument("--camera", required=True, help="camera config TOML (dictionary, marker -> robot map)")
    p.add_argument("--calibration", required=True, help="floor calibration JSON from `vsfleet tracker calibrate`")
    p.add_argument("--source", required=True,
                   help="camera index, video file, stream URL, or 'render' (synthetic camera over the truth)")
    p.add_argument("--fleet", default="demo")
    p.add_argument("--src", default=None, help="tracker id sent as 'src' (default: the config's)")
    p.add_argument("--rate", type=float, default=30.0, help="frame rate of --source render [Hz]")
    p.add_argument("--t0", type=float, default=None,
                   help="capture time of a video file's frame 0 [UNIX s] (default: its .json sidecar, else now)")
    p.add_argument("--no-pace", action="store_true", help="read a video file as fast as possible")
    p.add_argument("--retries", type=int, default=-1,
                   help="give up after this many failed opens/reads in a row (default: never)")
    p.add_argument("--verbose", "-v", action="store_true")
    add_zenoh_args(p)
    return p


def main(argv: list[str] | None = None) -> int:
    from fleetctl.zconf import init_logging, zenoh_config
    from vsfleet.wire import Keys, WireError, check_name

    args = build_parser().parse_args(argv)
    init_logging(args.verbose)
    quiet_opencv(args.verbose)
    try:
        Keys(args.fleet)
        if args.src is not None:
            check_name(args.src, "src")
        if args.rate <= 0:
            raise ConfigError("--rate must be > 0")
        config = load_config(args.camera)
        calibration = FloorCalibration.load(args.calibration)
        if args.source == "render":
            spec = sim_camera_from_dict(config.sim_camera, f"{args.camera}: [sim_camera]")
            if (spec.width_px, spec.height_px) != (calibration.width_px, calibration.height_px):
                raise ConfigError(f"the sim camera is {spec.width_px}x{spec.height_px} px, the calibration is "
                                  f"for {calibration.width_px}x{calibration.height_px} px")
        elif not is_live(args.source) and not Path(args.source).exists():
            raise ConfigError(f"no such video file {args.source!r} (a camera is an index such as 0, "
                              "a stream a URL)")
        t0 = video_t0(args.source, args.t0)
        CameraTracker(config, calibration)  # a homography at the wrong height fails here, before zenoh
    except (ConfigError, CalibrationError, WireError) as exc:
        log.error("%s", exc)
        return 2
    stats = run_camera_tracker(zenoh_config(args), config, calibration, args.source, args.fleet, args.src,
                               args.rate, t0, not args.no_pace, args.retries)
    return 1 if stats.gave_up else 0


if __name__ == "__main__":
    raise SystemExit(main())
