"""ArUco markers on robots -> world poses: the camera config, the detector and the pure tracker core.

``CameraTracker.process(image, t_s)`` finds the markers in one frame, maps
marker ids to robots, projects the corners onto the marker plane with the
floor calibration and returns one ``PoseMsg`` per robot, all with this
frame's ``seq`` and the tracker's ``src``. No I/O and no clock: the capture
time ``t_s`` is passed in.
"""

from __future__ import annotations

import logging
import math
import re
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from vsfleet.zglue.lifecycle import Rejections
from vsfleet.geometry import wrap_angle
from vsfleet.wire import PoseMsg, WireError, check_name

from .calib import FloorCalibration, Reference, marker_pose_from_corners

log = logging.getLogger("vsfleet.tracker.camera")

DEFAULT_DICTIONARY = "DICT_4X4_50"


class ConfigError(ValueError):
    """A camera config file that is missing or malformed."""


class FrameError(RuntimeError):
    """A frame that cannot be used: empty, wrong type or wrong size."""


def aruco_dictionary(name: str) -> cv2.aruco.Dictionary:
    """OpenCV's predefined dictionary by name, e.g. ``DICT_4X4_50``; ConfigError if unknown."""
    code = getattr(cv2.aruco, name, None) if name.startswith("DICT_") else None
    if not isinstance(code, int):
        known = sorted(n for n in dir(cv2.aruco) if n.startswith("DICT_"))
        raise ConfigError(f"unknown ArUco dictionary {name!r}; expected one of {', '.join(known)}")
    return cv2.aruco.getPredefinedDictionary(code)


@dataclass(frozen=True)
class MarkerMount:
    """Which robot wears a marker, and how it is turned: robot heading = marker heading + offset."""

    robot: str
    heading_offset_rad: float = 0.0


@dataclass(frozen=True)
class CameraConfig:
    """One camera's tracker config (TOML); see deploy/camera/overhead.toml."""

    src: str                               # tracker id sent as 'src'; one per camera (required)
    dictionary: str = DEFAULT_DICTIONARY
    marker_size_m: float = 0.10            # side of the black square
    marker_height_m: float = 0.10          # marker plane above the floor
    size_tolerance: float = 0.25           # a seen marker whose side is off by more is rejected
    markers: dict[int, MarkerMount] = field(default_factory=dict)
    references: tuple[Reference, ...] = ()
    sim_camera: dict[str, Any] | None = None  # [sim_camera], read by tracker.render


def _number(doc: dict, name: str, default: float | None, where: str, positive: bool = False) -> float:
    v = doc.get(name, default)
    if v is None:
        raise ConfigError(f"{where}: missing {name!r}")
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise ConfigError(f"{where}: {name!r} must be a finite number, got {v!r}")
    if positive and v <= 0:
        raise ConfigError(f"{where}: {name!r} must be > 0, got {v}")
    return float(v)


CONFIG_KEYS = {"src", "dictionary", "marker_size_m", "marker_height_m", "size_tolerance", "markers", "references",
               "sim_camera"}
MOUNT_KEYS = {"robot", "heading_offset_rad"}
REFERENCE_KEYS = {"id", "x_m", "y_m", "th_rad", "size_m", "z_m"}
MARKER_ID = re.compile(r"[0-9]+")


def _no_unknown_keys(table: dict, known: set[str], where: str) -> None:
    unknown = sorted(set(table) - known)
    if unknown:
        raise ConfigError(f"{where}: unknown keys {unknown} (expected some of {sorted(known)})")


def config_from_dict(doc: dict, where: str = "camera config") -> CameraConfig:
    """Validate a parsed camera config; ConfigError names the first problem."""
    _no_unknown_keys(doc, CONFIG_KEYS, where)
    if "src" not in doc:
        raise ConfigError(f"{where}: missing 'src' (this camera's tracker id, e.g. src = \"cam1\"; "
                          "one per camera)")
    try:
        src = check_name(doc["src"], "src")
    except WireError as exc:
        raise ConfigError(f"{where}: {exc}") from None
    dictionary = doc.get("dictionary", DEFAULT_DICTIONARY)
    if not isinstance(dictionary, str):
        raise ConfigError(f"{where}: 'dictionary' must be a name such as {DEFAULT_DICTIONARY!r}")
    n_ids = aruco_dictionary(dictionary).bytesList.shape[0]
    markers: dict[int, MarkerMount] = {}
    table = doc.get("markers", {})
    if not isinstance(table, dict):
        raise ConfigError(f"{where}: [markers] must map marker ids to robot ids")
    for key, v in table.items():
        if not MARKER_ID.fullmatch(key):  # int() would also take "1_0", "+2", " 3" and other digits
            raise ConfigError(f"{where}: marker id {key!r} is not an integer (plain digits 0-9)")
        marker_id = int(key)
        if marker_id in markers:
            raise ConfigError(f"{where}: marker id {marker_id} is given twice")
        if not 0 <= marker_id < n_ids:
            raise ConfigError(f"{where}: marker id {marker_id} is not in {dictionary} (0..{n_ids - 1})")
        if isinstance(v, str):
            v = {"robot": v}
        if not isinstance(v, dict):
            raise ConfigError(f"{where}: marker {marker_id} must map to a robot id or {{robot, heading_offset_rad}}")
        _no_unknown_keys(v, MOUNT_KEYS, f"{where}: marker {marker_id}")
        try:
            robot = check_name(v.get("robot"), "robot")
        except WireError as exc:
            raise ConfigError(f"{where}: marker {marker_id}: {exc}") from None
        markers[marker_id] = MarkerMount(robot, _number(v, "heading_offset_rad", 0.0, f"{where}: marker {marker_id}"))
    robots = [m.robot for m in markers.values()]
    if len(set(robots)) != len(robots):
        raise ConfigError(f"{where}: a robot wears more than one marker")
    refs = []
    ref_list = doc.get("references", [])
    if not isinstance(ref_list, list):
        raise ConfigError(f"{where}: [[references]] must be a list of tables")
    for i, r in enumerate(ref_list):
        w = f"{where}: reference #{i + 1}"
        if not isinstance(r, dict) or not isinstance(r.get("id"), int) or isinstance(r.get("id"), bool):
            raise ConfigError(f"{w}: needs an integer 'id'")
        _no_unknown_keys(r, REFERENCE_KEYS, w)
        if not 0 <= r["id"] < n_ids or r["id"] in markers:
            raise ConfigError(f"{w}: id {r['id']} must be in {dictionary} and not worn by a robot")
        refs.append(Reference(r["id"], _number(r, "x_m", None, w), _number(r, "y_m", None, w),
                              _number(r, "th_rad", 0.0, w), _number(r, "size_m", None, w, positive=True),
                              _number(r, "z_m", 0.0, w)))
    if len({r.marker_id for r in refs}) != len(refs):
        raise ConfigError(f"{where}: two references share an id")
    sim = doc.get("sim_camera")
    if sim is not None and not isinstance(sim, dict):
        raise ConfigError(f"{where}: [sim_camera] must be a table")
    tol = _number(doc, "size_tolerance", 0.25, where, positive=True)
    return CameraConfig(src=src, dictionary=dictionary,
                        marker_size_m=_number(doc, "marker_size_m", 0.10, where, positive=True),
                        marker_height_m=_number(doc, "marker_height_m", 0.10, where),
                        size_tolerance=tol, markers=markers, references=tuple(refs), sim_camera=sim)


def load_config(path: str | Path) -> CameraConfig:
    """Read and validate a camera config TOML file; ConfigError if missing or malformed."""
    try:
        text = Path(path).read_text()
    except OSError as exc:
        raise ConfigError(f"cannot read camera config {path}: {exc.strerror or exc}") from None
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: not valid TOML: {exc}") from None
    return config_from_dict(doc, str(path))


class MarkerDetector:
    """cv2.aruco.ArucoDetector with sub-pixel corners; ``detect`` -> {marker id: [(4, 2) px, ...]}."""

    def __init__(self, dictionary: str = DEFAULT_DICTIONARY) -> None:
        params = cv2.aruco.DetectorParameters()
        params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
        params.cornerRefinementWinSize = 3
        params.cornerRefinementMaxIterations = 50
        params.cornerRefinementMinAccuracy = 0.01
        self.detector = cv2.aruco.ArucoDetector(aruco_dictionary(dictionary), params)

    def detect(self, image: np.ndarray) -> dict[int, list[np.ndarray]]:
        gray = as_gray(image)
        corners, ids, _ = self.detector.detectMarkers(gray)
        out: dict[int, list[np.ndarray]] = {}
        if ids is None:
            return out
        for c, i in zip(corners, ids.ravel()):
            out.setdefault(int(i), []).append(np.asarray(c, dtype=float).reshape(4, 2))
        return out


def as_gray(image: np.ndarray) -> np.ndarray:
    """An 8-bit grey image from a grey or BGR(A) frame; FrameError for anything else."""
    if not isinstance(image, np.ndarray) or image.size == 0:
        raise FrameError("empty frame")
    if image.dtype != np.uint8:
        raise FrameError(f"frame must be 8-bit, got {image.dtype}")
    if image.ndim == 2:
        return image
    if image.ndim == 3 and image.shape[2] in (3, 4):
        return cv2.cvtColor(image, cv2.COLOR_BGR2GRAY if image.shape[2] == 3 else cv2.COLOR_BGRA2GRAY)
    raise FrameError(f"frame must be grey or BGR, got shape {image.shape}")


def size_ok(side_m: float, size_m: float, tolerance: float) -> bool:
    """A measured side within ``tolerance`` (a fraction) of ``size_m``; NaN or inf is never ok."""
    return bool(abs(side_m / size_m - 1.0) <= tolerance)


class CameraTracker:
    """One camera's frames -> poses. Pure: no I/O, no clock; one ``seq`` per processed frame."""

    def __init__(self, config: CameraConfig, calibration: FloorCalibration, src: str | None = None) -> None:
        self.config = config
        self.calibration = calibration
        self.src = src or config.src
        self.detector = MarkerDetector(config.dictionary)
        self.seq = 0
        self.rejections = Rejections(log)
        calibration.check_plane(config.marker_height_m)  # a homography at another height, a camera below: raise

    def check_frame(self, image: np.ndarray) -> np.ndarray:
        gray = as_gray(image)
        want = (self.calibration.height_px, self.calibration.width_px)
        if gray.shape != want:
            raise FrameError(f"frame is {gray.shape[1]}x{gray.shape[0]} px, the calibration is for "
                             f"{want[1]}x{want[0]} px")
        return gray

    def process(self, image: np.ndarray, t_s: float) -> list[tuple[str, PoseMsg]]:
        """Poses of every robot whose marker is seen in ``image`` (captured at ``t_s``), sorted by robot.

        Raises FrameError for an unusable frame (no seq is used then). Unknown
        ids, a marker seen twice and a marker of the wrong size are rejected (counted).
        """
        gray = self.check_frame(image)
        seen = self.detector.detect(gray)
        self.seq += 1
        cfg = self.config
        out = []
        for marker_id, quads in sorted(seen.items()):
            key = f"camera/{self.src}/marker/{marker_id}"
            mount = cfg.markers.get(marker_id)
            if mount is None:
                if not any(r.marker_id == marker_id for r in cfg.references):
                    self.rejections.reject(key, f"marker id {marker_id} maps to no robot")
                continue
            if len(quads) > 1:
                self.rejections.reject(key, f"marker id {marker_id} seen {len(quads)} times in one frame")
                continue
            corners_xy = self.calibration.to_plane(quads[0], cfg.marker_height_m)
            if not np.all(np.isfinite(corners_xy)):
                self.rejections.reject(key, f"marker id {marker_id}: its corners' rays do not meet the marker "
                                            "plane in front of the camera (a wrong calibration?)")
                continue
            x, y, th, side_m = marker_pose_from_corners(corners_xy)
            if not size_ok(side_m, cfg.marker_size_m, cfg.size_tolerance):
                self.rejections.reject(key, f"marker id {marker_id} measures {1000 * side_m:.0f} mm, "
                                            f"expected {1000 * cfg.marker_size_m:.0f} mm")
                continue
            out.append((mount.robot, PoseMsg(t=float(t_s), seq=self.seq, x=x, y=y,
                                             th=wrap_angle(th + mount.heading_offset_rad), src=self.src)))
        return sorted(out, key=lambda rp: rp[0])
