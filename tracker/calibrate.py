"""vsfleet tracker calibrate: the floor calibration from reference markers at known floor positions.

Reads one image (or up to ``--frames`` frames of a video, camera or stream,
averaging the corners), finds the config's ``[[references]]`` markers and fits
a homography, or with ``--intrinsics`` the camera's floor pose (pinhole
model). Writes the calibration JSON and reports the reprojection error on the
floor in mm.

``--source render`` calibrates the config's synthetic camera (``[sim_camera]``, as ``vsfleet
tracker camera --source render`` sees the fleet) on its rendered references, with its own
intrinsics; ``--robots`` refuses a config that maps no marker to one of them. `vsfleet run
--tracker camera` starts this before the camera loop.
"""

from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

import cv2
import numpy as np

from vsfleet.zglue.program import Refused, common_flags, program, refusing

from .calib import CalibrationError, FloorCalibration, Intrinsics, fit_calibration
from .markers import CameraConfig, ConfigError, FrameError, MarkerDetector, as_gray, load_config
from .render import Renderer, reference_scene, sim_camera_from_dict
from .sources import IMAGE_SUFFIXES, CameraOpenError, is_live, open_capture, quiet_opencv

log = logging.getLogger("vsfleet.tracker.calibrate")


def read_frames(source: str, n_frames: int) -> list[np.ndarray]:
    """Up to ``n_frames`` frames of an image file, video file, camera index, device, stream URL or pipeline."""
    live = is_live(source)
    if not live and not Path(source).exists():
        raise CameraOpenError(f"no such image or video file {source!r}")
    if not live and Path(source).suffix.lower() in IMAGE_SUFFIXES:
        image = cv2.imread(source, cv2.IMREAD_UNCHANGED)
        if image is None:
            raise CameraOpenError(f"cannot read image {source!r}")
        return [image]
    cap = open_capture(source)
    try:
        if not cap.isOpened():
            raise CameraOpenError(f"cannot open camera source {source!r}")
        frames = []
        while len(frames) < n_frames:
            ok, image = cap.read()
            if not ok or image is None:
                break
            frames.append(image)
    finally:
        cap.release()
    if not frames:
        raise CameraOpenError(f"camera source {source!r} gave no frame")
    return frames


def calibrate_frames(frames: list[np.ndarray], config: CameraConfig,
                     intrinsics: Intrinsics | None = None) -> FloorCalibration:
    """Detect the references in every frame, average each one's corners, and fit the calibration."""
    if not config.references:
        raise ConfigError("the camera config lists no [[references]]")
    detector = MarkerDetector(config.dictionary)
    wanted = {r.marker_id for r in config.references}
    seen: dict[int, list[np.ndarray]] = {}
    size = None
    for image in frames:
        gray = as_gray(image)
        if size is not None and gray.shape != size:
            raise FrameError("frames of different sizes")
        size = gray.shape
        for marker_id, quads in detector.detect(gray).items():
            if marker_id in wanted and len(quads) == 1:
                seen.setdefault(marker_id, []).append(quads[0])
    mean = {i: np.mean(q, axis=0) for i, q in seen.items()}
    return fit_calibration(mean, config.references, size[1], size[0], intrinsics)


def calibrate_render(camera: str | Path, robots: tuple[str, ...] = ()) -> FloorCalibration:
    """The calibration of ``camera``'s synthetic camera on its rendered reference markers.

    ConfigError when the config has no [sim_camera] or maps no marker to one of ``robots`` (the
    camera loop could not see them).
    """
    config = load_config(camera)
    if config.sim_camera is None:
        raise ConfigError(f"{camera}: no [sim_camera] table, so nothing to render for the camera loop")
    mapped = {m.robot for m in config.markers.values()}
    missing = sorted(set(robots) - mapped)
    if missing:
        raise ConfigError(f"{camera}: no marker maps to robot(s) {missing} (its [markers] map "
                          f"{sorted(mapped)}): the camera could not see them")
    renderer = Renderer(sim_camera_from_dict(config.sim_camera, f"{camera}: [sim_camera]"), config.dictionary)
    calibration = calibrate_frames([renderer.render(reference_scene(config), 0.0)], config,
                                   renderer.camera.intrinsics)
    e = calibration.error_mm
    log.info("camera %s calibrated on its rendered references: reprojection error mean %.2f mm, max %.2f mm",
             config.src, e["mean"], e["max"])
    return calibration


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="vsfleet tracker calibrate", description=__doc__.splitlines()[0])
    p.add_argument("--camera", required=True, help="camera config TOML with [[references]]")
    p.add_argument("--source", required=True,
                   help="image file, video file, camera index, /dev/video* device, stream URL, GStreamer pipeline, "
                        "or 'render' (the config's synthetic camera, its rendered references)")
    p.add_argument("--out", required=True, help="calibration JSON to write")
    p.add_argument("--intrinsics", help="camera intrinsics JSON: fit the pinhole model (floor pose)")
    p.add_argument("--frames", type=int, default=10, help="frames to average from a video or camera")
    p.add_argument("--robots", default="", help="--source render: comma-separated robots a marker must map to")
    return common_flags(p, zenoh=False)


@program(build_parser, log)
def main(args: argparse.Namespace) -> int:
    quiet_opencv(args.verbose)
    with refusing(ConfigError, CalibrationError, CameraOpenError, FrameError):
        if args.frames < 1:
            raise ConfigError("--frames must be >= 1")
        if args.source == "render":
            if args.intrinsics:
                raise ConfigError("--source render fits with the synthetic camera's own intrinsics; drop --intrinsics")
            frames = [None]
            calibration = calibrate_render(args.camera, tuple(r for r in args.robots.split(",") if r))
        else:
            config = load_config(args.camera)
            intrinsics = Intrinsics.load(args.intrinsics) if args.intrinsics else None
            frames = read_frames(args.source, args.frames)
            calibration = calibrate_frames(frames, config, intrinsics)
    try:
        calibration.save(args.out)
    except OSError as exc:
        raise Refused(f"cannot write {args.out}: {exc.strerror or exc}") from exc
    e = calibration.error_mm
    print(f"{calibration.model} calibration from {len(e['markers'])} reference markers "
          f"({e['points']} corners, {len(frames)} frame(s)) written to {args.out}")
    print(f"reprojection error on the floor: mean {e['mean']:.2f} mm, rms {e['rms']:.2f} mm, max {e['max']:.2f} mm")
    sys.stdout.flush()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
