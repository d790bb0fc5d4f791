"""Camera sources: what ``--source`` names, opening it, and OpenCV's own logging; shared by
``tracker camera`` and ``tracker calibrate``."""

from __future__ import annotations

import re

import cv2

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".pgm", ".ppm")
_INDEX = re.compile(r"[0-9]+")
_PIPELINE = re.compile(r"!\s*appsink\b")


class CameraOpenError(RuntimeError):
    """The camera, file or stream cannot be opened. ``fatal``: do not retry (a video file)."""

    def __init__(self, message: str, fatal: bool = False) -> None:
        super().__init__(message)
        self.fatal = fatal


def source_kind(spec: str) -> str:
    """What ``--source`` names: 'render', 'index', 'device', 'pipeline', 'url' or 'file'."""
    if spec == "render":
        return "render"
    if _INDEX.fullmatch(spec):
        return "index"
    if spec.startswith("/dev/"):
        return "device"
    if _PIPELINE.search(spec):
        return "pipeline"
    if "://" in spec:
        return "url"
    return "file"


def is_live(spec: str, force: bool = False) -> bool:
    """A live source: its frames are timed by the clock at grab, and a failure is a disconnect (retried).
    Everything but a video file is live; ``force`` (``--live``) makes any source live."""
    return force or source_kind(spec) != "file"


def gstreamer_available() -> bool:
    return bool(cv2.videoio_registry.hasBackend(cv2.CAP_GSTREAMER))


def open_capture(spec: str) -> cv2.VideoCapture:
    """cv2.VideoCapture of a camera index, a GStreamer pipeline, or a device, URL or file path."""
    kind = source_kind(spec)
    if kind == "index":
        return cv2.VideoCapture(int(spec))
    if kind == "pipeline":
        return cv2.VideoCapture(spec, cv2.CAP_GSTREAMER)
    return cv2.VideoCapture(spec)


def quiet_opencv(verbose: bool) -> None:
    """OpenCV's own warnings (a camera that does not open, ...) only with --verbose; ours say it once."""
    if not verbose:
        cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_ERROR)
