"""l2: the weighted 2-D Procrustes rotation without reflection (closed form)."""

from __future__ import annotations

import math


def rotation(prob) -> float:
    """th = atan2(sum w P x Q, sum w P . Q) [rad]; 0 when rounding hides the rotation.

    P, Q: the problem's centred template and robot points.  The rotation is unobservable
    when |(cross, dot)| <= 1e-13 sqrt(sum w |P|^2 sum w |Q|^2) (>= sum w |P||Q|).
    """
    P, Q = prob.P, prob.Q
    if not prob.unit:
        P = prob.w[:, None] * P
    dot = float((P * Q).sum())
    cross = float((P[:, 0] * Q[:, 1] - P[:, 1] * Q[:, 0]).sum())
    mag = math.sqrt(float((P * prob.P).sum()) * float((prob.w[:, None] * Q * Q).sum() if not prob.unit else (Q * Q).sum()))
    if math.hypot(cross, dot) <= 1e-13 * mag:
        return 0.0
    return math.atan2(cross, dot)
