"""vsfleet render: synthetic overhead camera frames of the simulated robots and their ArUco markers.

``Renderer.render(scene, t_s)`` is pure apart from its seeded noise: a
perspective pinhole camera (optionally with lens distortion) over a tiled
floor, a dark disc per robot with its marker on top, lens blur, sensor noise,
vignetting and lighting that changes with time. ``vsfleet render`` subscribes
to ``vs/<fleet>/truth/*`` and writes a video (FFV1, lossless) with a sidecar
``<video>.json`` holding the capture time of frame 0; it can also write the
calibration frame (reference markers only) and the camera's intrinsics.
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Sequence

import cv2
import numpy as np

from vsfleet.wire import TruthMsg
from vsfleet.zglue.program import common_flags, program, refusing

from .calib import CalibrationError, PinholeCamera, marker_corners_world
from .markers import CameraConfig, ConfigError, aruco_dictionary

log = logging.getLogger("vsfleet.render")

SUPERSAMPLE = 6
BLACK, WHITE, BODY = 25.0, 235.0, 55.0   # reflectance x 255 of ink, paper and the robot's top


@dataclass(frozen=True)
class SimCameraSpec:
    """The synthetic camera: geometry [px, m] and image degradations."""

    width_px: int = 1280
    height_px: int = 720
    f_px: float = 800.0
    position_m: tuple[float, float, float] = (1.0, 0.5, 2.5)
    look_at_m: tuple[float, float, float] = (1.0, 0.55, 0.0)
    dist_coeffs: tuple[float, ...] = ()
    blur_sigma_px: float = 0.8        # lens blur (Gaussian)
    noise_sigma_grey: float = 3.0     # sensor noise, standard deviation [grey levels, 0..255]
    light_gain: tuple[float, float] = (0.7, 1.05)  # global illumination swings between these
    light_period_s: float = 8.0
    light_gradient: float = 0.2       # +- fraction across the image, turning with time
    vignetting: float = 0.3           # darkening at the image corners
    body_radius_m: float = 0.09       # dark disc under each robot's marker
    seed: int = 0

    def camera(self) -> PinholeCamera:
        return PinholeCamera.look_at(self.width_px, self.height_px, self.f_px, self.position_m,
                                     self.look_at_m, self.dist_coeffs)


def sim_camera_from_dict(doc: dict | None, where: str = "[sim_camera]") -> SimCameraSpec:
    """Validate a ``[sim_camera]`` table (None: the defaults); ConfigError on a bad field."""
    doc = dict(doc or {})
    base = SimCameraSpec()
    kw = {}
    for name, default in base.__dict__.items():
        if name not in doc:
            continue
        v = doc.pop(name)
        if isinstance(default, tuple):
            n = {"position_m": 3, "look_at_m": 3, "light_gain": 2}.get(name)
            if not isinstance(v, list) or (n is not None and len(v) != n) or not all(
                    isinstance(e, (int, float)) and not isinstance(e, bool) and math.isfinite(e) for e in v):
                raise ConfigError(f"{where}: {name!r} must be a list of {n or 'some'} numbers")
            kw[name] = tuple(float(e) for e in v)
        elif isinstance(default, int):
            if not isinstance(v, int) or isinstance(v, bool) or (v <= 0 and name != "seed"):
                raise ConfigError(f"{where}: {name!r} must be a positive integer")
            kw[name] = v
        else:
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v < 0:
                raise ConfigError(f"{where}: {name!r} must be a number >= 0")
            kw[name] = float(v)
    if doc:
        raise ConfigError(f"{where}: unknown keys {sorted(doc)}")
    spec = SimCameraSpec(**kw)
    if spec.f_px <= 0 or spec.light_period_s <= 0 or spec.position_m[2] <= 0:
        raise ConfigError(f"{where}: f_px, light_period_s and the camera height must be > 0")
    return spec


@dataclass(frozen=True)
class SceneMarker:
    """A marker in the scene: id, centre (x, y, z) [m; world], heading of its top edge [rad], side [m]."""

    marker_id: int
    x_m: float
    y_m: float
    th_rad: float
    size_m: float
    z_m: float
    body_radius_m: float = 0.0   # > 0: a dark robot top under the marker


class Renderer:
    """Draws scenes through one camera; the floor, marker textures and noise are made once."""

    def __init__(self, spec: SimCameraSpec, dictionary: str) -> None:
        self.spec = spec
        self.camera = spec.camera()
        self.dictionary = aruco_dictionary(dictionary)
        self.rng = np.random.default_rng(spec.seed)
        w, h = spec.width_px, spec.height_px
        self.background = self._floor()
        u = (np.arange(w, dtype=np.float32) - (w - 1) / 2) / (w / 2)
        v = (np.arange(h, dtype=np.float32) - (h - 1) / 2) / (w / 2)
        self.u, self.v = u[None, :], v[:, None]
        r2 = self.u ** 2 + self.v ** 2
        self.vignette = (1.0 - spec.vignetting * r2 / r2.max()).astype(np.float32)
        pad = 32
        self.noise = [self.rng.normal(0.0, spec.noise_sigma_grey, (h + pad, w + pad)).astype(np.float32)
                      for _ in range(2)] if spec.noise_sigma_grey > 0 else []
        self.textures: dict[int, tuple[np.ndarray, np.ndarray]] = {}

    def _floor(self) -> np.ndarray:
        """Reflectance of the floor (z = 0) seen by every pixel: 0.5 m tiles with seams and mottling."""
        w, h = self.spec.width_px, self.spec.height_px
        uu, vv = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
        xy = self.camera.to_plane(np.column_stack([uu.ravel(), vv.ravel()]), 0.0)
        x, y = xy[:, 0].reshape(h, w), xy[:, 1].reshape(h, w)
        tile = 0.5
        fx, fy = np.abs((x / tile) - np.round(x / tile)) * tile, np.abs((y / tile) - np.round(y / tile)) * tile
        seam = np.minimum(fx, fy) < 0.004
        mottle = 12 * np.sin(2.1 * x + 0.7) * np.sin(3.3 * y + 1.3) + 6 * np.sin(9.0 * x - 5.0 * y)
        checker = 10 * ((np.floor(x / tile) + np.floor(y / tile)) % 2)
        floor = 150 + mottle + checker - 60 * seam
        return np.clip(np.nan_to_num(floor, nan=150.0), 0, 255).astype(np.float32)  # NaN: pixels above the horizon

    def _texture(self, marker_id: int) -> tuple[np.ndarray, np.ndarray]:
        """Marker at one pixel per cell with a one-cell white quiet zone, and its coverage mask."""
        if marker_id not in self.textures:
            bits = self.dictionary.markerSize + 2
            img = cv2.aruco.generateImageMarker(self.dictionary, marker_id, bits, borderBits=1)
            tex = np.pad(np.where(img > 127, WHITE, BLACK).astype(np.float32), 1, constant_values=WHITE)
            self.textures[marker_id] = (tex, np.ones_like(tex))
        return self.textures[marker_id]

    def _paint(self, img: np.ndarray, corners_px: np.ndarray, src: np.ndarray, mask: np.ndarray) -> None:
        """Composite texture ``src`` onto ``img`` inside the quad ``corners_px``, anti-aliased by supersampling."""
        h_img, w_img = img.shape
        x0, y0 = np.floor(corners_px.min(axis=0)).astype(int) - 2
        x1, y1 = np.ceil(corners_px.max(axis=0)).astype(int) + 3
        x0, y0, x1, y1 = max(x0, 0), max(y0, 0), min(x1, w_img), min(y1, h_img)
        if x1 <= x0 or y1 <= y0:
            return
        s = SUPERSAMPLE
        n = src.shape[0]
        src_q = np.float32([[-0.5, -0.5], [n - 0.5, -0.5], [n - 0.5, n - 0.5], [-0.5, n - 0.5]])
        dst_q = ((corners_px - (x0, y0) + 0.5) * s - 0.5).astype(np.float32)
        hom = cv2.getPerspectiveTransform(src_q, dst_q)
        size = ((x1 - x0) * s, (y1 - y0) * s)
        warped = cv2.warpPerspective(src, hom, size, flags=cv2.INTER_NEAREST, borderValue=0)
        cover = cv2.warpPerspective(mask, hom, size, flags=cv2.INTER_NEAREST, borderValue=0)
        small = (x1 - x0, y1 - y0)
        warped = cv2.resize(warped, small, interpolation=cv2.INTER_AREA)
        cover = cv2.resize(cover, small, interpolation=cv2.INTER_AREA)
        roi = img[y0:y1, x0:x1]
        roi *= 1.0 - cover
        roi += warped

    def _body(self, img: np.ndarray, m: SceneMarker) -> None:
        a = np.linspace(0.0, 2 * np.pi, 48, endpoint=False)
        ring = np.column_stack([m.x_m + m.body_radius_m * np.cos(a), m.y_m + m.body_radius_m * np.sin(a),
                                np.full(len(a), m.z_m - 0.002)])
        px = self.camera.project(ring)
        cv2.fillPoly(img, [np.round(px * 16).astype(np.int32)], BODY, cv2.LINE_AA, shift=4)

    def scene_image(self, scene: Sequence[SceneMarker]) -> np.ndarray:
        """The noise-free, evenly lit image (float32 grey levels) of ``scene``."""
        img = self.background.copy()
        for m in sorted(scene, key=lambda m: m.z_m):
            if m.body_radius_m > 0:
                self._body(img, m)
            n = self.dictionary.markerSize
            quiet_m = m.size_m * (n + 4) / (n + 2)
            corners_px = self.camera.project(marker_corners_world(m.x_m, m.y_m, m.th_rad, quiet_m, m.z_m))
            self._paint(img, corners_px, *self._texture(m.marker_id))
        return img

    def render(self, scene: Sequence[SceneMarker], t_s: float) -> np.ndarray:
        """The camera's 8-bit grey frame of ``scene`` at time ``t_s`` (lighting depends on t)."""
        spec = self.spec
        img = self.scene_image(scene)
        phase = 2 * math.pi * t_s / spec.light_period_s
        lo, hi = spec.light_gain
        gain = lo + (hi - lo) * 0.5 * (1 + math.sin(phase))
        turn = phase / 1.7
        ramp = self.u * math.cos(turn) + self.v * math.sin(turn)  # a gradient whose direction turns with t
        img *= self.vignette * (gain * (1.0 + spec.light_gradient * ramp))
        if spec.blur_sigma_px > 0:
            img = cv2.GaussianBlur(img, (0, 0), spec.blur_sigma_px)
        if self.noise:
            h, w = img.shape
            bank = self.noise[int(self.rng.integers(len(self.noise)))]
            dy, dx = self.rng.integers(0, bank.shape[0] - h), self.rng.integers(0, bank.shape[1] - w)
            img += bank[dy:dy + h, dx:dx + w]
        return np.clip(img, 0, 255).astype(np.uint8)


def robot_scene(config: CameraConfig, spec: SimCameraSpec, poses_world: dict[str, tuple[float, float, float]]
                ) -> list[SceneMarker]:
    """Scene markers for robot poses {robot: (x, y, th)} [m, rad; world], as ``config`` mounts them."""
    out = []
    for marker_id, mount in config.markers.items():
        pose = poses_world.get(mount.robot)
        if pose is not None:
            out.append(SceneMarker(marker_id, pose[0], pose[1], pose[2] - mount.heading_offset_rad,
                                   config.marker_size_m, config.marker_height_m, spec.body_radius_m))
    return out


def reference_scene(config: CameraConfig) -> list[SceneMarker]:
    return [SceneMarker(r.marker_id, r.x_m, r.y_m, r.th_rad, r.size_m, r.z_m) for r in config.references]


def render_frame(config: CameraConfig, poses_world: dict[str, tuple[float, float, float]], t_s: float = 0.0,
                 spec: SimCameraSpec | None = None) -> np.ndarray:
    """One frame of robots at ``poses_world`` through the config's sim camera (pure, seeded)."""
    spec = spec or sim_camera_from_dict(config.sim_camera)
    return Renderer(spec, config.dictionary).render(robot_scene(config, spec, poses_world), t_s)


class TruthBook:
    """The latest truth per robot (thread-safe); fed by a zenoh subscriber."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.truth: dict[str, TruthMsg] = {}

    def offer(self, robot: str, msg: TruthMsg) -> None:
        with self.lock:
            held = self.truth.get(robot)
            if held is None or msg.t > held.t:
                self.truth[robot] = msg

    def fresh(self, now_s: float, max_age_s: float) -> tuple[float, dict[str, tuple[float, float, float]]] | None:
        """(capture time = newest truth t, poses) of robots with truth at most max_age_s old; None if none."""
        with self.lock:
            recent = {r: m for r, m in self.truth.items() if now_s - m.t <= max_age_s}
        if not recent:
            return None
        return max(m.t for m in recent.values()), {r: (m.x, m.y, m.th) for r, m in recent.items()}


# ---------------------------------------------------------------- the command


def write_video(path: Path, fps: float, size: tuple[int, int]) -> cv2.VideoWriter:
    fourcc = cv2.VideoWriter_fourcc(*("FFV1" if path.suffix.lower() in (".avi", ".mkv") else "mp4v"))
    writer = cv2.VideoWriter(str(path), fourcc, fps, size, False)
    if not writer.isOpened():
        raise OSError(f"cannot write video {path}")
    return writer


def record_video(book: TruthBook, renderer: Renderer, config: CameraConfig, out: Path, fps: float,
                 duration_s: float, stop, clock: Callable[[], float]) -> int:
    """Render the latest truth at ``fps`` into ``out`` until ``duration_s`` or stop; returns frames written."""
    from vsfleet.zglue.lifecycle import pace

    spec = renderer.spec
    writer = write_video(out, fps, (spec.width_px, spec.height_px))
    t0 = None
    frames = 0
    try:
        while not stop.is_set():
            now = clock()
            got = book.fresh(now, 0.1)
            if got is None:
                stop.wait(0.05)
                continue
            if t0 is None:
                t0 = now
                log.info("first frame at t0 = %.3f", t0)
            if frames >= max(1, round(duration_s * fps)):
                break
            t_frame = t0 + frames / fps
            pace(t_frame, stop, clock)
            got = book.fresh(clock(), 0.1)
            if got is None:
                continue
            writer.write(renderer.render(robot_scene(config, spec, got[1]), t_frame))
            frames += 1
    finally:
        writer.release()
        sidecar = {"t0_s": t0, "fps": fps, "frames": frames}
        Path(str(out) + ".json").write_text(json.dumps(sidecar) + "\n")
    return frames


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="vsfleet render", description=__doc__.splitlines()[0])
    p.add_argument("--camera", required=True, help="camera config TOML (its [sim_camera] table)")
    p.add_argument("--fleet", default="demo")
    p.add_argument("--out", help="video file to write from the fleet's truth (.avi: lossless FFV1)")
    p.add_argument("--fps", type=float, default=30.0)
    p.add_argument("--duration", type=float, default=60.0, help="video length [s]")
    p.add_argument("--calibration-image", metavar="PNG", help="write the reference markers' frame and exit")
    p.add_argument("--write-intrinsics", metavar="JSON", help="write the sim camera's intrinsics and exit")
    return common_flags(p)


@program(build_parser, log)
def main(args: argparse.Namespace) -> int:
    with refusing(ConfigError, CalibrationError, OSError):
        from .markers import load_config

        config = load_config(args.camera)
        spec = sim_camera_from_dict(config.sim_camera, f"{args.camera}: [sim_camera]")
        if args.fps <= 0 or args.duration <= 0:
            raise ConfigError("--fps and --duration must be > 0")
        renderer = Renderer(spec, config.dictionary)
        if args.write_intrinsics:
            renderer.camera.intrinsics.save(args.write_intrinsics)
            log.info("intrinsics written to %s", args.write_intrinsics)
        if args.calibration_image:
            if not config.references:
                raise ConfigError(f"{args.camera}: no [[references]] to draw")
            if not cv2.imwrite(args.calibration_image, renderer.render(reference_scene(config), 0.0)):
                raise OSError(f"cannot write {args.calibration_image}")
            log.info("calibration frame written to %s", args.calibration_image)
        if not args.out:
            if not (args.write_intrinsics or args.calibration_image):
                raise ConfigError("nothing to do: give --out, --calibration-image or --write-intrinsics")
            return 0
    return run_render(args, config, renderer)


def run_render(args: argparse.Namespace, config: CameraConfig, renderer: Renderer) -> int:
    import zenoh

    from vsfleet.zglue.lifecycle import Rejections, StopFlag, wall_clock
    from vsfleet.zglue.zconf import open_session, zenoh_config
    from vsfleet.wire import Keys, decode_truth

    keys = Keys(args.fleet)
    book = TruthBook()
    rejections = Rejections(log)
    stop = StopFlag()

    def on_truth(sample: zenoh.Sample) -> None:
        key = str(sample.key_expr)
        try:
            book.offer(keys.robot_of(key, "truth"), decode_truth(sample.payload.to_bytes()))
        except Exception as exc:  # noqa: BLE001 - WireError, or anything else: counted, never fatal
            rejections.reject(key, str(exc))

    with open_session(zenoh_config(args)) as session:
        sub = session.declare_subscriber(keys.truth(), on_truth)
        try:
            frames = record_video(book, renderer, config, Path(args.out), args.fps, args.duration, stop, wall_clock)
        except OSError as exc:
            log.error("%s", exc)
            return 2
        finally:
            sub.undeclare()
    log.info("wrote %d frames to %s (capture times in %s.json)", frames, args.out, args.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
