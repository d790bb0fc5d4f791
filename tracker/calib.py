"""Floor calibration of an overhead camera: pixels to world (x, y) on a horizontal plane.

Two models, both saved as JSON (``FloorCalibration.save``/``load``):
- ``homography``: image px -> (x, y) [m] on the plane z = ``plane_z_m`` of the
  reference markers. Exact for a pinhole camera without lens distortion, and
  only for markers at that height.
- ``pinhole``: intrinsics (camera matrix, distortion) plus the floor pose
  (rvec, tvec: world -> camera). Maps a pixel onto any plane z = h, so markers
  on top of robots are placed without parallax error.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import cv2
import numpy as np

CALIBRATION_FORMAT = "vsfleet-floor-calibration"
INTRINSICS_FORMAT = "vsfleet-camera-intrinsics"


class CalibrationError(ValueError):
    """A calibration or intrinsics file that is missing, malformed or unusable."""


# ---------------------------------------------------------------- markers on the floor


def marker_corners_world(x_m: float, y_m: float, th_rad: float, size_m: float, z_m: float = 0.0) -> np.ndarray:
    """The 4 corners (4, 3) [m; world] of a square marker, in OpenCV's order.

    Order: top-left, top-right, bottom-right, bottom-left of the printed marker;
    the marker's top edge runs along its heading ``th_rad`` (left to right).
    """
    h = size_m / 2.0
    local = np.array([[-h, h], [h, h], [h, -h], [-h, -h]])
    c, s = math.cos(th_rad), math.sin(th_rad)
    xy = local @ np.array([[c, s], [-s, c]]) + (x_m, y_m)
    return np.column_stack([xy, np.full(4, z_m)])


def marker_pose_from_corners(corners_world_xy: np.ndarray) -> tuple[float, float, float, float]:
    """(x [m], y [m], th [rad], mean side [m]) of a marker from its 4 world corners (OpenCV order)."""
    c = np.asarray(corners_world_xy, dtype=float)
    x, y = c.mean(axis=0)
    d = (c[1] - c[0]) + (c[2] - c[3])
    side_m = float(np.mean(np.linalg.norm(c - np.roll(c, -1, axis=0), axis=1)))
    return float(x), float(y), math.atan2(d[1], d[0]), side_m


# ---------------------------------------------------------------- camera models


@dataclass(frozen=True)
class Intrinsics:
    """Pinhole intrinsics: camera matrix [px] and OpenCV distortion coefficients, for one image size."""

    width_px: int
    height_px: int
    camera_matrix: np.ndarray   # (3, 3)
    dist_coeffs: np.ndarray     # (n,), n in 4, 5, 8, 12, 14

    def to_dict(self) -> dict:
        return {"format": INTRINSICS_FORMAT, "image_size_px": [self.width_px, self.height_px],
                "camera_matrix": self.camera_matrix.tolist(), "dist_coeffs": self.dist_coeffs.tolist()}

    def save(self, path: str | Path) -> None:
        Path(path).write_text(json.dumps(self.to_dict(), indent=2) + "\n")

    @staticmethod
    def load(path: str | Path) -> "Intrinsics":
        return intrinsics_from_dict(_read_json(path, "intrinsics"), str(path))


@dataclass(frozen=True)
class PinholeCamera:
    """A posed pinhole camera: intrinsics plus the world -> camera rotation and translation."""

    intrinsics: Intrinsics
    rvec: np.ndarray  # (3,) Rodrigues, world -> camera
    tvec: np.ndarray  # (3,) [m]

    @property
    def rotation(self) -> np.ndarray:
        return cv2.Rodrigues(np.asarray(self.rvec, dtype=float))[0]

    @property
    def centre_world(self) -> np.ndarray:
        return -self.rotation.T @ np.asarray(self.tvec, dtype=float)

    @staticmethod
    def look_at(width_px: int, height_px: int, f_px: float, position_m: Sequence[float],
                target_m: Sequence[float], dist_coeffs: Sequence[float] = ()) -> "PinholeCamera":
        """A camera at ``position_m`` looking at ``target_m``; image up is world +y as far as possible."""
        c = np.asarray(position_m, dtype=float)
        z = np.asarray(target_m, dtype=float) - c
        z /= np.linalg.norm(z)
        up = np.array([0.0, 1.0, 0.0]) if abs(z[1]) < 0.99 else np.array([1.0, 0.0, 0.0])
        y = -(up - (up @ z) * z)
        y /= np.linalg.norm(y)
        x = np.cross(y, z)
        rot = np.vstack([x, y, z])
        k = np.array([[f_px, 0.0, (width_px - 1) / 2.0], [0.0, f_px, (height_px - 1) / 2.0], [0.0, 0.0, 1.0]])
        dist = np.zeros(5) if len(dist_coeffs) == 0 else np.asarray(dist_coeffs, dtype=float)
        return PinholeCamera(Intrinsics(width_px, height_px, k, dist), cv2.Rodrigues(rot)[0].ravel(), -rot @ c)

    def project(self, points_world: np.ndarray) -> np.ndarray:
        """Pixels (N, 2) of world points (N, 3) [m]."""
        pts = np.asarray(points_world, dtype=float).reshape(-1, 1, 3)
        px, _ = cv2.projectPoints(pts, np.asarray(self.rvec, float), np.asarray(self.tvec, float),
                                  self.intrinsics.camera_matrix, self.intrinsics.dist_coeffs)
        return px.reshape(-1, 2)

    @property
    def axis_world(self) -> np.ndarray:
        """The optical axis (unit vector, world): the camera's +z."""
        return self.rotation[2]

    def to_plane(self, pixels: np.ndarray, z_m: float) -> np.ndarray:
        """World (x, y) [m] (N, 2) where the rays through ``pixels`` (N, 2) meet the plane z = z_m.

        A ray that meets the plane behind the camera, or never (parallel), gives NaN.
        """
        px = np.asarray(pixels, dtype=float).reshape(-1, 1, 2)
        norm = cv2.undistortPoints(px, self.intrinsics.camera_matrix, self.intrinsics.dist_coeffs).reshape(-1, 2)
        rays_w = np.column_stack([norm, np.ones(len(norm))]) @ self.rotation  # R^T d, row-wise
        c = self.centre_world
        with np.errstate(divide="ignore", invalid="ignore"):
            s = (z_m - c[2]) / rays_w[:, 2]
            xy = c[:2] + s[:, None] * rays_w[:, :2]
        bad = ~(np.isfinite(s) & (s > 0)) | ~np.all(np.isfinite(xy), axis=1)
        xy[bad] = np.nan
        return xy


@dataclass(frozen=True)
class FloorCalibration:
    """Pixels -> world (x, y) on a plane z = h; see the module docstring for the two models."""

    model: str                      # "homography" or "pinhole"
    width_px: int
    height_px: int
    homography: np.ndarray | None = None    # image px -> plane (x, y) [m]
    plane_z_m: float = 0.0                  # the homography's plane
    camera: PinholeCamera | None = None
    error_mm: dict | None = None            # reprojection error on the floor: mean, max, rms

    def check_plane(self, z_m: float) -> None:
        """CalibrationError unless markers at height ``z_m`` can be placed: a homography holds only for
        its own plane; a pinhole camera must be above that plane."""
        if self.model == "pinhole":
            cz = float(self.camera.centre_world[2])
            if not cz > z_m:
                raise CalibrationError(f"the calibrated camera is at z = {cz:.3f} m, not above the markers' "
                                       f"plane z = {z_m:.3f} m: the calibration is wrong")
        elif abs(z_m - self.plane_z_m) > 1e-3:
            raise CalibrationError(
                f"a homography calibration holds only for markers at z = {self.plane_z_m:.3f} m, not "
                f"{z_m:.3f} m: calibrate with the reference markers at the robots' marker height, or "
                "give --intrinsics for a pinhole calibration")

    def to_plane(self, pixels: np.ndarray, z_m: float) -> np.ndarray:
        """World (x, y) [m] of image points on the plane z = z_m (homography: only its own plane).

        Rows are NaN for pixels that see no point of the plane in front of the camera (beyond the
        horizon) or map to no finite point.
        """
        self.check_plane(z_m)
        if self.model == "pinhole":
            return self.camera.to_plane(pixels, z_m)
        px = np.asarray(pixels, dtype=float).reshape(-1, 2)
        w = np.column_stack([px, np.ones(len(px))]) @ self.homography[2]
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            xy = cv2.perspectiveTransform(px.reshape(-1, 1, 2), self.homography).reshape(-1, 2)
        bad = ~(w * homography_side(self.homography, self.width_px, self.height_px) > 0) | \
            ~np.all(np.isfinite(xy), axis=1)
        xy[bad] = np.nan
        return xy

    def to_dict(self) -> dict:
        d: dict = {"format": CALIBRATION_FORMAT, "version": 1, "model": self.model,
                   "image_size_px": [self.width_px, self.height_px]}
        if self.model == "homography":
            d["homography"] = self.homography.tolist()
            d["plane_z_m"] = self.plane_z_m
        else:
            cam = self.camera
            d["camera_matrix"] = cam.intrinsics.camera_matrix.tolist()
            d["dist_coeffs"] = cam.intrinsics.dist_coeffs.tolist()
            d["rvec"] = np.asarray(cam.rvec, float).ravel().tolist()
            d["tvec"] = np.asarray(cam.tvec, float).ravel().tolist()
        if self.error_mm is not None:
            d["reprojection_error_mm"] = self.error_mm
        return d

    def save(self, path: str | Path) -> None:
        Path(path).write_text(json.dumps(self.to_dict(), indent=2) + "\n")

    @staticmethod
    def load(path: str | Path) -> "FloorCalibration":
        return calibration_from_dict(_read_json(path, "calibration"), str(path))


# ---------------------------------------------------------------- file parsing


def _read_json(path: str | Path, what: str) -> dict:
    try:
        text = Path(path).read_text()
    except OSError as exc:
        raise CalibrationError(f"cannot read {what} file {path}: {exc.strerror or exc}") from None
    try:
        doc = json.loads(text)
    except json.JSONDecodeError as exc:
        raise CalibrationError(f"{path}: not valid JSON: {exc}") from None
    if not isinstance(doc, dict):
        raise CalibrationError(f"{path}: expected a JSON object")
    return doc


def _matrix(doc: dict, name: str, shape: tuple[int, ...], where: str) -> np.ndarray:
    if name not in doc:
        raise CalibrationError(f"{where}: missing field {name!r}")
    try:
        a = np.asarray(doc[name], dtype=float)
    except (TypeError, ValueError):
        raise CalibrationError(f"{where}: field {name!r} must be numbers") from None
    if a.shape != shape or not np.all(np.isfinite(a)):
        raise CalibrationError(f"{where}: field {name!r} must be finite numbers of shape {list(shape)}, "
                               f"got shape {list(a.shape)}")
    return a


def _size(doc: dict, where: str) -> tuple[int, int]:
    s = doc.get("image_size_px")
    if not (isinstance(s, list) and len(s) == 2 and all(isinstance(v, int) and v > 0 for v in s)):
        raise CalibrationError(f"{where}: field 'image_size_px' must be [width, height] in pixels")
    return s[0], s[1]


def _dist(doc: dict, where: str) -> np.ndarray:
    d = doc.get("dist_coeffs", [])
    try:
        a = np.asarray(d, dtype=float).ravel()
    except (TypeError, ValueError):
        raise CalibrationError(f"{where}: field 'dist_coeffs' must be numbers") from None
    if len(a) not in (0, 4, 5, 8, 12, 14) or not np.all(np.isfinite(a)):
        raise CalibrationError(f"{where}: field 'dist_coeffs' must hold 0, 4, 5, 8, 12 or 14 finite numbers")
    return a if len(a) else np.zeros(5)


INTRINSICS_KEYS = ("format", "image_size_px", "camera_matrix", "dist_coeffs")
CALIBRATION_KEYS = {"homography": ("format", "version", "model", "image_size_px", "reprojection_error_mm",
                                   "homography", "plane_z_m"),
                    "pinhole": ("format", "version", "model", "image_size_px", "reprojection_error_mm",
                                "camera_matrix", "dist_coeffs", "rvec", "tvec")}


def _no_unknown_keys(doc: dict, known, where: str) -> None:
    unknown = sorted(set(doc) - set(known))
    if unknown:
        raise CalibrationError(f"{where}: unknown field(s) {unknown} (expected some of {sorted(known)})")


def intrinsics_from_dict(doc: dict, where: str = "intrinsics", check_keys: bool = True) -> Intrinsics:
    if check_keys:
        _no_unknown_keys(doc, INTRINSICS_KEYS, where)
    w, h = _size(doc, where)
    k = _matrix(doc, "camera_matrix", (3, 3), where)
    if k[0, 0] <= 0 or k[1, 1] <= 0:
        raise CalibrationError(f"{where}: focal lengths in 'camera_matrix' must be > 0")
    return Intrinsics(w, h, k, _dist(doc, where))


def image_corners(width_px: int, height_px: int) -> np.ndarray:
    return np.array([[0.0, 0.0], [width_px - 1.0, 0.0], [width_px - 1.0, height_px - 1.0], [0.0, height_px - 1.0]])


def homography_side(hom: np.ndarray, width_px: int, height_px: int) -> float:
    """The sign (+1, -1) of the homogeneous w over the whole image, or 0 if the plane's horizon (w = 0)
    crosses the image. w is affine in the pixel, so the image's 4 corners decide."""
    w = np.column_stack([image_corners(width_px, height_px), np.ones(4)]) @ hom[2]
    if np.all(w > 0):
        return 1.0
    if np.all(w < 0):
        return -1.0
    return 0.0


def check_geometry(cal: FloorCalibration, where: str) -> FloorCalibration:
    """CalibrationError unless the calibration describes a camera above the floor looking down at it."""
    if cal.model == "pinhole":
        cam = cal.camera
        c, axis = cam.centre_world, cam.axis_world
        if not np.all(np.isfinite(c)) or not c[2] > 0:
            raise CalibrationError(f"{where}: the camera centre is at z = {c[2]:.3f} m: not above the floor "
                                   "(a mirrored solvePnP solution, or a wrong rvec/tvec)")
        if not axis[2] < 0:
            raise CalibrationError(f"{where}: the camera does not look down (optical axis z = {axis[2]:.3f}): "
                                   "an overhead camera must face the floor")
    elif homography_side(cal.homography, cal.width_px, cal.height_px) == 0.0:
        raise CalibrationError(f"{where}: the homography puts the plane's horizon inside the image: "
                               "not an overhead camera looking down at the floor")
    return cal


def calibration_from_dict(doc: dict, where: str = "calibration") -> FloorCalibration:
    if doc.get("format") != CALIBRATION_FORMAT:
        raise CalibrationError(f"{where}: not a floor calibration (field 'format' must be {CALIBRATION_FORMAT!r})")
    model = doc.get("model")
    if model in CALIBRATION_KEYS:
        _no_unknown_keys(doc, CALIBRATION_KEYS[model], where)
    w, h = _size(doc, where)
    err = doc.get("reprojection_error_mm")
    if model == "homography":
        hom = _matrix(doc, "homography", (3, 3), where)
        if abs(np.linalg.det(hom)) < 1e-12:
            raise CalibrationError(f"{where}: the homography is singular")
        z = doc.get("plane_z_m", 0.0)
        if isinstance(z, bool) or not isinstance(z, (int, float)) or not math.isfinite(z):
            raise CalibrationError(f"{where}: field 'plane_z_m' must be a number")
        return check_geometry(
            FloorCalibration("homography", w, h, homography=hom, plane_z_m=float(z), error_mm=err), where)
    if model == "pinhole":
        intr = intrinsics_from_dict(doc, where, check_keys=False)
        cam = PinholeCamera(intr, _matrix(doc, "rvec", (3,), where), _matrix(doc, "tvec", (3,), where))
        return check_geometry(FloorCalibration("pinhole", w, h, camera=cam, error_mm=err), where)
    raise CalibrationError(f"{where}: field 'model' must be 'homography' or 'pinhole', got {model!r}")


# ---------------------------------------------------------------- fitting


@dataclass(frozen=True)
class Reference:
    """A calibration marker lying at a known place: centre (x, y, z) [m; world], heading [rad], side [m]."""

    marker_id: int
    x_m: float
    y_m: float
    th_rad: float
    size_m: float
    z_m: float = 0.0

    def corners_world(self) -> np.ndarray:
        return marker_corners_world(self.x_m, self.y_m, self.th_rad, self.size_m, self.z_m)


MIN_REFERENCES = 3


def fit_calibration(seen: dict[int, np.ndarray], references: Sequence[Reference], width_px: int,
                    height_px: int, intrinsics: Intrinsics | None = None) -> FloorCalibration:
    """Fit a calibration to the detected corners ``seen`` {marker id: (4, 2) px} of the references.

    With ``intrinsics``: the pinhole model (solvePnP). Without: a homography,
    which needs every reference on one plane. Raises CalibrationError.
    """
    refs = [r for r in references if r.marker_id in seen]
    if len(refs) < MIN_REFERENCES:
        missing = sorted(r.marker_id for r in references if r.marker_id not in seen)
        raise CalibrationError(f"only {len(refs)} of {len(references)} reference markers seen (at least "
                               f"{MIN_REFERENCES} needed); not seen: {missing}")
    world = np.vstack([r.corners_world() for r in refs])
    pixels = np.vstack([np.asarray(seen[r.marker_id], dtype=float).reshape(4, 2) for r in refs])
    if intrinsics is not None:
        if (intrinsics.width_px, intrinsics.height_px) != (width_px, height_px):
            raise CalibrationError(f"intrinsics are for {intrinsics.width_px}x{intrinsics.height_px} px, "
                                   f"the image is {width_px}x{height_px} px")
        ok, rvec, tvec = cv2.solvePnP(world, pixels, intrinsics.camera_matrix, intrinsics.dist_coeffs,
                                      flags=cv2.SOLVEPNP_ITERATIVE)
        if not ok:
            raise CalibrationError("solvePnP found no camera pose for the reference markers")
        rvec, tvec = cv2.solvePnPRefineLM(world, pixels, intrinsics.camera_matrix, intrinsics.dist_coeffs,
                                          rvec, tvec)
        cal = FloorCalibration("pinhole", width_px, height_px,
                               camera=PinholeCamera(intrinsics, rvec.ravel(), tvec.ravel()))
    else:
        zs = {r.z_m for r in refs}
        if max(zs) - min(zs) > 1e-6:
            raise CalibrationError("reference markers at different heights need --intrinsics "
                                   "(a homography maps one plane)")
        hom, _ = cv2.findHomography(pixels, world[:, :2], 0)
        if hom is None:
            raise CalibrationError("no homography fits the reference markers (are they collinear?)")
        cal = FloorCalibration("homography", width_px, height_px, homography=hom, plane_z_m=refs[0].z_m)
    check_geometry(cal, "the fitted calibration")
    errors_m = np.concatenate([
        np.linalg.norm(cal.to_plane(seen[r.marker_id], r.z_m) - r.corners_world()[:, :2], axis=1) for r in refs])
    error_mm = {"mean": float(1000 * errors_m.mean()), "max": float(1000 * errors_m.max()),
                "rms": float(1000 * np.sqrt(np.mean(errors_m ** 2))), "points": int(len(errors_m)),
                "markers": [r.marker_id for r in refs]}
    return FloorCalibration(cal.model, width_px, height_px, cal.homography, cal.plane_z_m, cal.camera, error_mm)
