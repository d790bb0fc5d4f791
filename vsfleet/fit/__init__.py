"""Fitting the virtual structure to the robots (Tan & Lewis 1996, section 3.3.1).

Find the rigid pose T = (x, y, th) minimising l1 = sum w_i d_i, l2 = sqrt(sum w_i d_i^2) or
linf = max w_i d_i, with d_i = |r_i - R(th) p_i - (x, y)| [m].  l2 is closed form; l1 and linf
are certified global optima (gap <= CERT_TOL weighted m).  Method, certificate, degenerate
cases and determinism: docs/fit.md.

``fit_structure`` and ``structure_cost`` run the compiled core (vsfleet/_core/vs_fit.c, a port of
this package's numpy code); ``fit_structure_reference`` and ``structure_cost_reference`` are the
numpy code, kept as the readable reference (tests/test_core_fit.py holds the two together).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from ..lazy import lazy_numpy
from .. import _core
from ..coreconst import FIT_MAX_ABS as MAX_ABS, METRIC_CODES as _CODES, METRICS
from ..errors import NonFiniteError, ShapeError, UnknownMetricError, WeightError
from ..geometry import Pose2, wrap_angle
from . import certify, median, minimax, procrustes
from .certify import CERT_TOL, Problem

np = lazy_numpy(globals())   # numpy on first use: the agent process never loads it (vsfleet.lazy)

__all__ = ["CERT_TOL", "METRICS", "FitResult", "fit_structure", "fit_structure_reference", "structure_cost",
           "structure_cost_reference"]

_EVALUATORS = {"l1": median.evaluate, "linf": minimax.evaluate}
# MAX_ABS: the largest accepted |coordinate| [m] and weight: beyond it squares overflow (vs_fit.h VS_FIT_MAX_ABS).


@dataclass(frozen=True, eq=False)
class FitResult:
    """Result of :func:`fit_structure`.

    pose: the fitted structure pose (world <- structure).
    cost: the metric's cost at ``pose`` [weighted m].
    residuals_m: (n,) unweighted distances d_i = |r_i - pose(p_i)| [m], all robots.
    metric: 'l1', 'l2' or 'linf'.
    cost_lower_bound: certified lower bound of the optimal cost [weighted m]
        (equal to ``cost`` for l2 and closed-form cases).
    """

    pose: Pose2
    cost: float
    residuals_m: np.ndarray
    metric: str
    cost_lower_bound: float


def _as_array(name: str, a, error, ndim: int) -> np.ndarray:
    """A finite float copy of ``a``; ``error`` (a ValueError type) for anything else."""
    shape = "(n, 2)" if ndim == 2 else "(n,)"
    try:
        if np.asarray(a).dtype.kind not in "iufO":  # bool, complex, strings...
            raise TypeError
        arr = np.array(a, dtype=float)
    except (TypeError, ValueError):
        raise error(f"{name} must be a real numeric {shape} array, got {type(a).__name__}") from None
    if arr.ndim != ndim or (ndim == 2 and arr.shape[1] != 2):
        raise error(f"{name} must be a real numeric {shape} array, got shape {arr.shape}")
    if not np.isfinite(arr).all():
        raise NonFiniteError(f"{name} holds NaN or infinity")
    if arr.size and float(np.abs(arr).max()) > MAX_ABS:
        raise NonFiniteError(f"{name} holds a magnitude over {MAX_ABS:g} (its square overflows)")
    return arr


def _validate(template_xy, positions_xy, metric, weights):
    if not isinstance(metric, str) or metric not in METRICS:
        raise UnknownMetricError(f"metric must be one of {METRICS}, got {metric!r}")
    p = _as_array("template_xy", template_xy, ShapeError, 2)
    r = _as_array("positions_xy", positions_xy, ShapeError, 2)
    if p.shape[0] != r.shape[0]:
        raise ShapeError(f"template_xy has {p.shape[0]} points but positions_xy has {r.shape[0]}")
    if p.shape[0] == 0:
        raise ShapeError("need at least one robot (n = 0)")
    if weights is None:
        return p, r, None
    w = _as_array("weights", weights, WeightError, 1)
    if w.shape != (p.shape[0],):
        raise WeightError(f"weights must have shape ({p.shape[0]},), got {w.shape}")
    if (w < 0.0).any() or not (w > 0.0).any():
        raise WeightError("weights must be >= 0 and not all zero")
    pos = w[w > 0.0]
    if metric == "linf" and (pos != pos[0]).any():
        raise WeightError("linf takes 0/equal weights only (a robot is in the fit or not)")
    return p, r, w


def _residuals(p: np.ndarray, r: np.ndarray, pose: Pose2) -> np.ndarray:
    c, s = math.cos(pose.th), math.sin(pose.th)
    dx = r[:, 0] - (c * p[:, 0] - s * p[:, 1] + pose.x)
    dy = r[:, 1] - (s * p[:, 0] + c * p[:, 1] + pose.y)
    return np.sqrt(dx * dx + dy * dy)


def _cost_of(d: np.ndarray, w, metric: str) -> float:
    wd = d if w is None else w * d
    if metric == "l1":
        return math.fsum(wd.tolist())
    if metric == "l2":
        return math.sqrt(math.fsum((wd * d).tolist()))
    return float(wd.max())


def _as_pose(pose) -> Pose2:
    if isinstance(pose, Pose2):
        return pose
    try:
        x, y, th = (float(v) for v in pose)
    except (TypeError, ValueError):
        raise ShapeError("pose must be a Pose2 or an (x, y, th) triple") from None
    if not all(math.isfinite(v) and abs(v) <= MAX_ABS for v in (x, y, th)):
        raise NonFiniteError("pose holds NaN, infinity or a magnitude over 1e150")
    return Pose2(x, y, th)


def structure_cost(template_xy, positions_xy, pose, metric: str, weights=None) -> float:
    """The fit objective at ``pose`` (a Pose2 or an (x, y, th) triple) [weighted m].

    Raises the same typed errors as :func:`fit_structure`.  Computed by the compiled core (sums
    in index order), so ``fit_structure(...).cost == structure_cost(..., fit.pose, ...)`` exactly.
    """
    p, r, w = _contiguous(*_validate(template_xy, positions_xy, metric, weights))
    pose = _as_pose(pose)
    return _core.fit_cost(p, r, w, _CODES[metric], pose.x, pose.y, pose.th)


def structure_cost_reference(template_xy, positions_xy, pose, metric: str, weights=None) -> float:
    """:func:`structure_cost` in numpy (math.fsum): the reference."""
    p, r, w = _validate(template_xy, positions_xy, metric, weights)
    return _cost_of(_residuals(p, r, _as_pose(pose)), w, metric)


def fit_structure(template_xy, positions_xy, metric: str = "l2", weights=None) -> FitResult:
    """The rigid pose (world <- structure) minimising the metric's cost: the compiled core (vs_fit).

    template_xy: (n, 2) structure-frame points p_i [m]; positions_xy: (n, 2) world positions
    r_i [m]; metric: 'l1', 'l2' or 'linf'; weights: optional (n,) >= 0 (0 drops a robot from
    the fit; linf takes 0/equal weights only).  Raises ShapeError, NonFiniteError,
    UnknownMetricError, WeightError.  The same mathematics and search as
    :func:`fit_structure_reference` (poses within 1e-9 m / rad of it where the optimum is unique;
    docs/fit.md).  ``cost - cost_lower_bound`` is the certified gap (<= CERT_TOL unless the core's
    work cap was hit).
    """
    code = _CODES.get(metric) if isinstance(metric, str) else None
    if code is not None and weights is None and _clean(template_xy) and _clean(positions_xy) \
            and len(template_xy) == len(positions_xy) and len(template_xy):
        p, r, w = template_xy, positions_xy, None  # float64 (n, 2) arrays: read in place, not copied
        try:
            d = np.empty(len(p))
            x, y, th, cost, lower, _rounds = _core.fit(p, r, None, code, d)
        except NonFiniteError:  # the core refuses NaN / inf; the full validation says which input
            _validate(template_xy, positions_xy, metric, weights)
            raise
    else:
        p, r, w = _contiguous(*_validate(template_xy, positions_xy, metric, weights))
        d = np.empty(len(p))
        x, y, th, cost, lower, _rounds = _core.fit(p, r, w, _CODES[metric], d)
    d.flags.writeable = False
    return FitResult(pose=Pose2(x, y, th), cost=cost, residuals_m=d, metric=metric, cost_lower_bound=lower)


def _contiguous(p, r, w):
    """C-contiguous copies where needed (np.array keeps a Fortran-ordered input's layout)."""
    return np.ascontiguousarray(p), np.ascontiguousarray(r), None if w is None else np.ascontiguousarray(w)


def _clean(a) -> bool:
    """A C-contiguous float64 (n, 2) ndarray (the core reads it as it is)."""
    return type(a) is np.ndarray and a.dtype.char == "d" and a.dtype.isnative and a.ndim == 2 and a.shape[1] == 2 and a.flags.c_contiguous



def fit_structure_reference(template_xy, positions_xy, metric: str = "l2", weights=None) -> FitResult:
    """The rigid pose (world <- structure) minimising the metric's cost: the numpy reference.

    template_xy: (n, 2) structure-frame points p_i [m]; positions_xy: (n, 2) world positions
    r_i [m]; metric: 'l1', 'l2' or 'linf'; weights: optional (n,) >= 0 (0 drops a robot from
    the fit; linf takes 0/equal weights only).  Raises ShapeError, NonFiniteError,
    UnknownMetricError, WeightError.
    """
    p, r, w = _validate(template_xy, positions_xy, metric, weights)
    if w is None or (w > 0.0).all():
        prob = Problem(p, r, w)
    else:
        keep = w > 0.0
        prob = Problem(p[keep], r[keep], w[keep])
    lower = None
    with np.errstate(all="ignore"):
        if prob.n == 1:
            th, tx, ty = 0.0, 0.0, 0.0
        elif metric == "l2" or prob.n == 2 or prob.rigid:
            th = 0.0 if metric != "l2" and prob.rigid else procrustes.rotation(prob)
            tx, ty = 0.0, 0.0
            if metric != "l2":
                tx, ty, lower = certify.translation_at(prob, _EVALUATORS[metric], th)
        else:
            th0, t0, lean = procrustes.rotation(prob), (0.0, 0.0), False
            if metric == "l1" and prob.n >= median.NEWTON_N:  # large n: start the search at a local optimum
                th0, t0, lean = median.newton(prob, th0)
            elif metric == "linf" and prob.n > 3:  # a local minimum and its centre: a lean first batch, laddered
                th0, t0, lean = minimax.descend(prob, th0)
            guess, split = (minimax.guesses(prob, th0) or [th0] * lean, minimax.SPLIT) if metric == "linf" else ((), 0)
            th, tx, ty, lower = certify.search(prob, _EVALUATORS[metric], th0, guess, split, t0=t0, lean=lean,
                                              refine=minimax.kinks if metric == "linf" else None)
    pose = prob.pose(th, tx, ty)
    d = _residuals(p, r, pose)
    cost = _cost_of(d, w, metric)
    d.flags.writeable = False
    lower = cost if lower is None else min(lower, cost)
    return FitResult(pose=pose, cost=cost, residuals_m=d, metric=metric, cost_lower_bound=lower)
