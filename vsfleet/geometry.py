"""2-D poses and frames.

Conventions: metres, radians counter-clockwise from +x. A structure pose maps a
template point p (structure frame) to the world as ``R(th) @ p + (x, y)``.
Angles are wrapped in exactly one place: :func:`wrap_angle`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from .lazy import lazy_numpy

np = lazy_numpy(globals())   # numpy on first use: the agent process never loads it (vsfleet.lazy)

TWO_PI = 2.0 * math.pi


def wrap_angle(th_rad: float) -> float:
    """Wrap an angle to [-pi, pi). The only angle-wrapping function in vsfleet."""
    w = math.fmod(float(th_rad) + math.pi, TWO_PI)
    if w < 0.0:
        w += TWO_PI
    return w - math.pi


def rotation(th_rad: float) -> np.ndarray:
    """2x2 rotation matrix R(th) [counter-clockwise]."""
    c, s = math.cos(th_rad), math.sin(th_rad)
    return np.array([[c, -s], [s, c]])


@dataclass(frozen=True)
class Pose2:
    """A rigid 2-D pose: position (x, y) [m; world frame], heading th [rad, CCW from +x].

    ``th`` is stored wrapped to [-pi, pi).
    """

    x: float
    y: float
    th: float

    def __post_init__(self) -> None:
        object.__setattr__(self, "x", float(self.x))
        object.__setattr__(self, "y", float(self.y))
        object.__setattr__(self, "th", wrap_angle(self.th))

    @property
    def xy(self) -> np.ndarray:
        """Position [m; world frame] as a (2,) array."""
        return np.array([self.x, self.y])

    def as_tuple(self) -> tuple[float, float, float]:
        return (self.x, self.y, self.th)

    def apply(self, points_xy: np.ndarray) -> np.ndarray:
        """Map points (n, 2) or (2,) from this pose's frame to the world: R(th) p + t."""
        p = np.asarray(points_xy, dtype=float)
        c, s = math.cos(self.th), math.sin(self.th)
        x = c * p[..., 0] - s * p[..., 1] + self.x
        y = s * p[..., 0] + c * p[..., 1] + self.y
        return np.stack([x, y], axis=-1)

    def inverse_apply(self, points_world_xy: np.ndarray) -> np.ndarray:
        """Map world points (n, 2) or (2,) into this pose's frame: R(-th) (q - t)."""
        q = np.asarray(points_world_xy, dtype=float)
        dx, dy = q[..., 0] - self.x, q[..., 1] - self.y
        c, s = math.cos(self.th), math.sin(self.th)
        return np.stack([c * dx + s * dy, -s * dx + c * dy], axis=-1)

    def compose(self, other: "Pose2") -> "Pose2":
        """self ∘ other: first other, then self (world <- self <- other)."""
        x, y = self.apply(np.array([other.x, other.y]))
        return Pose2(x, y, self.th + other.th)

    def inverse(self) -> "Pose2":
        c, s = math.cos(self.th), math.sin(self.th)
        return Pose2(-(c * self.x + s * self.y), s * self.x - c * self.y, -self.th)


def angle_diff(a_rad: float, b_rad: float) -> float:
    """Signed smallest rotation from b to a, in [-pi, pi)."""
    return wrap_angle(a_rad - b_rad)
