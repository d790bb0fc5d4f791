"""l2: the weighted 2-D Procrustes rotation without reflection (closed form)."""

from __future__ import annotations

import math


def rotation(prob) -> float:
    """th = atan2(sum w P x Q, sum w P . Q) [rad]; 0 when rounding hides the rotation.

    P, Q: the problem's centred template and robot points.  The rotation is unobservable
    when |(cross, dot)| <= 1e-13 sqrt(sum w |P|^2 sum w |Q|^2) (>= sum w |P||Q|).
    """
    P, Q = prob.P, prob.Q
    wP = P if prob.unit else prob.w[:, None] * P
    dot = float((wP * Q).sum())
    cross = float((wP[:, 0] * Q[:, 1] - wP[:, 1] * Q[:, 0]).sum())
    mag = math.sqrt(float((wP * P).sum()) * float((Q * Q if prob.unit else prob.w[:, None] * Q * Q).sum()))
    if math.hypot(cross, dot) <= 1e-13 * mag:
        return 0.0
    return math.atan2(cross, dot)
