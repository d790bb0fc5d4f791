"""A differential-drive robot's kinematic envelope."""

from __future__ import annotations

import math
from dataclasses import dataclass

from .lazy import lazy_numpy
from .errors import EnvelopeError

np = lazy_numpy(globals())   # numpy on first use: the agent process never loads it (vsfleet.lazy)


@dataclass(frozen=True)
class Envelope:
    """Kinematic limits of one differential-drive robot.

    wheel_base_m: distance between the wheels' contact points [m].
    wheel_speed_max_m_s: largest wheel ground speed, either sign [m/s].
    wheel_accel_max_m_s2: largest change of one wheel's speed per second [m/s^2].
    """

    wheel_base_m: float
    wheel_speed_max_m_s: float
    wheel_accel_max_m_s2: float

    def __post_init__(self) -> None:
        for name in ("wheel_base_m", "wheel_speed_max_m_s", "wheel_accel_max_m_s2"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)):
                raise EnvelopeError(f"{name} must be a number, got {type(v).__name__}")
            if not math.isfinite(v) or v <= 0.0:
                raise EnvelopeError(f"{name} must be finite and > 0, got {v!r}")
            object.__setattr__(self, name, float(v))


@dataclass(frozen=True)
class Envelopes:
    """Kinematic limits of n robots as (n,) arrays, rows in the mission's sorted id order.

    Fields as :class:`Envelope`: wheel_base_m [m], wheel_speed_max_m_s [m/s], wheel_accel_max_m_s2 [m/s^2].
    """

    wheel_base_m: np.ndarray
    wheel_speed_max_m_s: np.ndarray
    wheel_accel_max_m_s2: np.ndarray

    def __post_init__(self) -> None:
        n = None
        for name in ("wheel_base_m", "wheel_speed_max_m_s", "wheel_accel_max_m_s2"):
            v = np.array(getattr(self, name), dtype=float)
            if v.ndim != 1 or (n is not None and v.shape[0] != n):
                raise EnvelopeError(f"{name} must be a 1-D array of the same length as the others")
            if not np.all(np.isfinite(v) & (v > 0.0)):
                raise EnvelopeError(f"{name} must be finite and > 0")
            n = v.shape[0]
            v.flags.writeable = False
            object.__setattr__(self, name, v)

    @classmethod
    def of(cls, envelopes) -> "Envelopes":
        """The arrays of a sequence of :class:`Envelope` (one per robot, in order)."""
        return cls(np.array([e.wheel_base_m for e in envelopes], dtype=float),
                   np.array([e.wheel_speed_max_m_s for e in envelopes], dtype=float),
                   np.array([e.wheel_accel_max_m_s2 for e in envelopes], dtype=float))

    def __len__(self) -> int:
        return int(self.wheel_base_m.shape[0])

    def row(self, i: int) -> Envelope:
        return Envelope(float(self.wheel_base_m[i]), float(self.wheel_speed_max_m_s[i]),
                        float(self.wheel_accel_max_m_s2[i]))
