"""A differential-drive robot's kinematic envelope."""

from __future__ import annotations

import math
from dataclasses import dataclass

from .errors import EnvelopeError


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
