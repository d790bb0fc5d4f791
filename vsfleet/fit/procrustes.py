"""l2: the weighted 2-D Procrustes rotation without reflection (closed form)."""

from __future__ import annotations

import math

import numpy as np


def rotation(prob) -> float:
    """th = atan2(sum w P x Q, sum w P . Q) [rad]; 0 when rounding hides the rotation.

    P, Q: the problem's centred template and robot points.  The threshold
    |(cross, dot)| <= 1e-13 sum w |P||Q| marks the rotation as unobservable.
    """
    Px, Py, Qx, Qy, w = prob.Px, prob.Py, prob.Qx, prob.Qy, prob.w
    dot = float(np.sum(w * (Px * Qx + Py * Qy)))
    cross = float(np.sum(w * (Px * Qy - Py * Qx)))
    mag = float(np.sum(w * np.sqrt((Px * Px + Py * Py) * (Qx * Qx + Qy * Qy))))
    if math.hypot(cross, dot) <= 1e-13 * mag:
        return 0.0
    return math.atan2(cross, dot)
