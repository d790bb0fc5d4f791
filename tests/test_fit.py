"""Fitting the virtual structure (Tan & Lewis 1996, section 3.3.1): l1, l2, linf."""

import dataclasses
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from vsfleet.errors import (
    NonFiniteError,
    ShapeError,
    UnknownMetricError,
    VsfleetValueError,
    WeightError,
)
from vsfleet.fit import CERT_TOL, FitResult, fit_structure, structure_cost
from vsfleet.geometry import Pose2, angle_diff

from vsfleet.fit import METRICS
FAST = settings(max_examples=25, deadline=None)
SLOW = settings(max_examples=12, deadline=None)

TRIANGLE = np.array([[0.3, 0.0], [-0.15, 0.26], [-0.15, -0.26]])


def spread_template(n: int, seed: int) -> np.ndarray:
    """n well-spread, non-collinear points in [-1, 1]^2 (deterministic in seed)."""
    rng = np.random.default_rng(seed)
    while True:
        p = rng.uniform(-1.0, 1.0, (n, 2))
        d = np.hypot(*(p[:, None, :] - p[None, :, :]).transpose(2, 0, 1))
        d[np.diag_indices(n)] = np.inf
        e = p - p.mean(axis=0)
        s = np.linalg.svd(e, compute_uv=False)
        if d.min() > 0.3 and s[-1] > 0.3 * s[0]:
            return p


def noisy_case(n: int, seed: int, noise: float = 0.05):
    rng = np.random.default_rng(seed + 10_000)
    p = spread_template(n, seed)
    g = Pose2(rng.uniform(-3, 3), rng.uniform(-3, 3), rng.uniform(-math.pi, math.pi))
    r = g.apply(p) + rng.normal(0.0, noise, (n, 2))
    return p, r


def pose_close(a: Pose2, b: Pose2, tol: float) -> bool:
    return abs(a.x - b.x) <= tol and abs(a.y - b.y) <= tol and abs(angle_diff(a.th, b.th)) <= tol


poses = st.builds(
    Pose2,
    st.floats(-5.0, 5.0),
    st.floats(-5.0, 5.0),
    st.floats(-math.pi, math.pi),
)
sizes = st.integers(3, 8)
seeds = st.integers(0, 10_000)


# ---------------------------------------------------------------- recovery


@FAST
@given(n=sizes, seed=seeds, g=poses, metric=st.sampled_from(METRICS))
def test_a_noise_free_fit_recovers_the_transform_for_every_metric(n, seed, g, metric):
    p = spread_template(n, seed)
    res = fit_structure(p, g.apply(p), metric)
    assert pose_close(res.pose, g, 1e-9)
    assert res.cost <= 1e-9
    assert np.all(res.residuals_m <= 1e-9)


@FAST
@given(n=sizes, seed=seeds, g=poses, metric=st.sampled_from(METRICS))
def test_moving_the_robots_rigidly_moves_the_fit_with_them(n, seed, g, metric):
    p, r = noisy_case(n, seed)
    base = fit_structure(p, r, metric)
    moved = fit_structure(p, g.apply(r), metric)
    assert moved.cost == pytest.approx(base.cost, abs=1e-9)
    if metric == "l2":
        assert pose_close(moved.pose, g.compose(base.pose), 1e-9)
    else:
        # the moved fit is optimal for the moved robots; so is G o base
        assert structure_cost(p, g.apply(r), g.compose(base.pose), metric) == pytest.approx(
            moved.cost, abs=1e-9
        )


# ---------------------------------------------------------------- optimality


def _cost_at(p, r, metric, weights=None):
    """v -> structure_cost(p, r, (v[0], v[1], v[2]), metric, weights), the same number, for scipy's searches (tens of
    thousands of calls a test): p, r and weights validated once, then the core's fit_cost at Pose2(x, y, th) as
    structure_cost computes it (a pose it would refuse still goes to structure_cost, which raises as before)."""
    from vsfleet import _core  # noqa: PLC0415
    from vsfleet.fit import MAX_ABS, _CODES, _contiguous, _validate  # noqa: PLC0415 - structure_cost's own steps
    pc, rc, wc = _contiguous(*_validate(p, r, metric, weights))
    code = _CODES[metric]

    def cost(v) -> float:
        x, y, th = float(v[0]), float(v[1]), float(v[2])
        if not (abs(x) <= MAX_ABS and abs(y) <= MAX_ABS and abs(th) <= MAX_ABS):   # NaN too
            return structure_cost(p, r, (x, y, th), metric, weights)
        pose = Pose2(x, y, th)
        return _core.fit_cost(pc, rc, wc, code, pose.x, pose.y, pose.th)

    return cost


def _powell(p, r, metric, x0, weights=None):
    from scipy.optimize import minimize  # noqa: PLC0415 - here: scipy.optimize is 0.1-0.3 s of each worker's collection
    cost = _cost_at(p, r, metric, weights)
    return minimize(cost, x0, method="Powell", options={"xtol": 1e-12, "ftol": 1e-15}).fun


@FAST
@given(
    n=sizes,
    seed=seeds,
    noise=st.sampled_from([0.01, 0.1, 0.5]),
    kicks=st.lists(st.tuples(st.floats(-0.3, 0.3), st.floats(-0.3, 0.3), st.floats(-0.5, 0.5)), min_size=1, max_size=6),
)
def test_the_linf_cost_is_never_above_a_perturbed_pose_or_powell(n, seed, noise, kicks):
    p, r = noisy_case(n, seed, noise)
    res = fit_structure(p, r, "linf")
    x, y, th = res.pose.as_tuple()
    for dx, dy, dth in kicks:
        for s in (1.0, 1e-3, 1e-6):
            other = structure_cost(p, r, (x + s * dx, y + s * dy, th + s * dth), "linf")
            assert res.cost <= other + 1e-12
    x0 = fit_structure(p, r, "l2").pose.as_tuple()
    assert res.cost <= _powell(p, r, "linf", x0) + 1e-12
    assert res.cost_lower_bound <= res.cost <= res.cost_lower_bound + 1e-9


@SLOW
@given(
    n=sizes,
    seed=seeds,
    noise=st.sampled_from([0.01, 0.1, 0.5]),
    kicks=st.lists(st.tuples(st.floats(-0.3, 0.3), st.floats(-0.3, 0.3), st.floats(-0.5, 0.5)), min_size=1, max_size=6),
)
def test_the_l1_cost_is_never_above_a_perturbed_pose_or_a_multistart_search(n, seed, noise, kicks):
    p, r = noisy_case(n, seed, noise)
    res = fit_structure(p, r, "l1")
    x, y, th = res.pose.as_tuple()
    for dx, dy, dth in kicks:
        for s in (1.0, 1e-3, 1e-6):
            other = structure_cost(p, r, (x + s * dx, y + s * dy, th + s * dth), "l1")
            assert res.cost <= other + CERT_TOL  # the certified gap (the search stops there)
    from scipy.optimize import minimize  # noqa: PLC0415 - as in _powell
    x0 = fit_structure(p, r, "l2").pose.as_tuple()
    cost = _cost_at(p, r, "l1")
    best = _powell(p, r, "l1", x0)
    for k in range(8):  # Nelder-Mead restarts around the circle
        start = [x0[0], x0[1], x0[2] + 2.0 * math.pi * k / 8]
        out = minimize(cost, start, method="Nelder-Mead", options={"xatol": 1e-12, "fatol": 1e-14, "maxiter": 4000})
        best = min(best, out.fun)
    assert res.cost <= best + 1e-7
    assert res.cost_lower_bound <= res.cost <= res.cost_lower_bound + 1e-9


def _ref_minimax(q: np.ndarray, w: np.ndarray) -> float:
    """Independent reference: brute force over all pairs and triples (unweighted)."""
    n = len(q)
    best = 0.0
    centres = []
    for i in range(n):
        for j in range(i + 1, n):
            centres.append(0.5 * (q[i] + q[j]))
            for k in range(j + 1, n):
                a, b, c = q[i], q[j], q[k]
                d = 2.0 * ((b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0]))
                if d != 0.0:
                    ux = ((c[1] - a[1]) * np.dot(b - a, b - a) - (b[1] - a[1]) * np.dot(c - a, c - a)) / d
                    uy = ((b[0] - a[0]) * np.dot(c - a, c - a) - (c[0] - a[0]) * np.dot(b - a, b - a)) / d
                    centres.append(a + np.array([ux, uy]))
    best = min(float(np.max(w * np.hypot(*(q - c).T))) for c in centres)
    return best


@pytest.mark.parametrize("seed", range(4))
def test_linf_matches_an_independent_brute_force_over_angles(seed):
    p, r = noisy_case(4, seed, 0.2)
    res = fit_structure(p, r, "linf")
    w = np.ones(4)
    grid = np.linspace(-math.pi, math.pi, 1441)
    vals = [_ref_minimax(r - Pose2(0, 0, th).apply(p), w) for th in grid]
    k = int(np.argmin(vals))
    # golden-section refinement of the best grid cell
    lo, hi = grid[max(k - 1, 0)], grid[min(k + 1, len(grid) - 1)]
    g = (math.sqrt(5) - 1) / 2
    for _ in range(60):
        a, b = hi - g * (hi - lo), lo + g * (hi - lo)
        fa = _ref_minimax(r - Pose2(0, 0, a).apply(p), w)
        fb = _ref_minimax(r - Pose2(0, 0, b).apply(p), w)
        if fa < fb:
            hi = b
        else:
            lo = a
    ref = min(min(vals), _ref_minimax(r - Pose2(0, 0, 0.5 * (lo + hi)).apply(p), w))
    assert res.cost <= ref + 1e-12
    assert res.cost >= ref - 1e-7


# ---------------------------------------------------------------- weights


@FAST
@given(n=st.integers(4, 8), seed=seeds, metric=st.sampled_from(METRICS), data=st.data())
def test_a_robot_with_weight_zero_is_ignored(n, seed, metric, data):
    p, r = noisy_case(n, seed, 0.1)
    k = data.draw(st.integers(0, n - 1))
    w = np.ones(n)
    w[k] = 0.0
    r_far = r.copy()
    r_far[k] += 100.0  # wherever that robot is, it must not matter
    res = fit_structure(p, r_far, metric, w)
    keep = np.arange(n) != k
    ref = fit_structure(p[keep], r[keep], metric)
    assert res.cost == pytest.approx(ref.cost, abs=1e-9)
    assert res.residuals_m.shape == (n,)
    assert res.residuals_m[k] > 50.0
    if metric == "l2":
        assert pose_close(res.pose, ref.pose, 1e-9)


@pytest.mark.parametrize("metric", ["l1", "l2"])
def test_weights_change_the_answer_towards_the_heavy_robot(metric):
    p, r = noisy_case(5, 7, 0.3)
    plain = fit_structure(p, r, metric)
    k = int(np.argmax(plain.residuals_m))
    w = np.ones(5)
    w[k] = 20.0
    heavy = fit_structure(p, r, metric, w)
    assert not pose_close(plain.pose, heavy.pose, 1e-6)
    assert heavy.residuals_m[k] < plain.residuals_m[k]


def test_weighted_costs_follow_their_documented_definitions():
    p, r = noisy_case(4, 3, 0.2)
    w = np.array([0.5, 2.0, 1.0, 3.0])
    pose = Pose2(0.1, -0.2, 0.3)
    d = np.hypot(*(r - pose.apply(p)).T)
    assert structure_cost(p, r, pose, "l1", w) == pytest.approx(np.sum(w * d), rel=1e-14)
    assert structure_cost(p, r, pose, "l2", w) == pytest.approx(math.sqrt(np.sum(w * d * d)), rel=1e-14)
    w3 = np.array([2.0, 2.0, 0.0, 2.0])
    assert structure_cost(p, r, pose, "linf", w3) == pytest.approx(np.max(w3 * d), rel=1e-14)
    assert structure_cost(p, r, pose.as_tuple(), "linf", w3) == structure_cost(p, r, pose, "linf", w3)


def test_linf_with_unequal_positive_weights_is_a_weight_error():
    with pytest.raises(WeightError):
        fit_structure(TRIANGLE, TRIANGLE, "linf", [1.0, 2.0, 1.0])
    res = fit_structure(TRIANGLE, TRIANGLE + 0.1, "linf", [3.0, 0.0, 3.0])
    assert res.residuals_m[0] == pytest.approx(res.residuals_m[2], abs=1e-12)


@pytest.mark.parametrize("metric", ["l1"])
@pytest.mark.parametrize("seed", range(3))
def test_weighted_fits_beat_powell_and_nearby_poses(metric, seed):
    p, r = noisy_case(6, seed, 0.2)
    w = np.random.default_rng(seed).uniform(0.2, 3.0, 6)
    res = fit_structure(p, r, metric, w)
    x0 = fit_structure(p, r, "l2", w).pose.as_tuple()
    assert res.cost <= _powell(p, r, metric, x0, w) + 1e-12
    x, y, th = res.pose.as_tuple()
    for d in ((1e-4, 0, 0), (0, -1e-4, 0), (0, 0, 1e-4), (0, 0, -1e-4), (1e-5, 1e-5, -1e-5)):
        assert res.cost <= structure_cost(p, r, (x + d[0], y + d[1], th + d[2]), metric, w) + 1e-12
    assert res.cost - res.cost_lower_bound <= 1e-9


# ---------------------------------------------------------------- degenerate inputs


def test_no_robots_is_a_shape_error():
    with pytest.raises(ShapeError):
        fit_structure(np.zeros((0, 2)), np.zeros((0, 2)))


@pytest.mark.parametrize("metric", METRICS)
def test_one_robot_sits_exactly_on_its_point_with_zero_rotation(metric):
    res = fit_structure([[0.3, -0.1]], [[2.0, 5.0]], metric)
    assert res.pose.th == 0.0
    assert res.pose.apply(np.array([0.3, -0.1])) == pytest.approx([2.0, 5.0], abs=1e-15)
    assert res.cost == 0.0


@pytest.mark.parametrize("metric", METRICS)
def test_two_robots_align_the_pair_and_split_the_gap(metric):
    p = np.array([[-0.5, 0.0], [0.5, 0.0]])
    r = np.array([[3.0, 1.0], [3.0, 2.5]])  # 1.5 m apart, template 1 m apart, rotated 90 deg
    res = fit_structure(p, r, metric)
    assert res.pose.th == pytest.approx(math.pi / 2, abs=1e-12)
    expected = {"l1": 0.5, "l2": math.sqrt(2 * 0.25**2), "linf": 0.25}[metric]
    assert res.cost == pytest.approx(expected, abs=1e-12)
    assert res.residuals_m == pytest.approx([0.25, 0.25], abs=1e-12)


@pytest.mark.parametrize("metric", METRICS)
def test_coincident_template_points_give_zero_rotation(metric):
    p = np.array([[0.2, 0.1]] * 4)
    r = np.array([[1.0, 1.0], [2.0, 1.0], [2.0, 2.0], [1.0, 2.5]])
    res = fit_structure(p, r, metric)
    assert res.pose.th == 0.0
    centre = res.pose.apply(p[0])
    expected = {"l2": r.mean(axis=0)}.get(metric)
    if expected is not None:
        assert centre == pytest.approx(expected, abs=1e-12)
    for d in ((1e-4, 0), (0, 1e-4), (-1e-4, 0), (0, -1e-4)):
        moved = Pose2(res.pose.x + d[0], res.pose.y + d[1], 0.0)
        assert res.cost <= structure_cost(p, r, moved, metric) + 1e-12


@pytest.mark.parametrize("metric", METRICS)
def test_coincident_robots_give_zero_rotation(metric):
    p = TRIANGLE
    r = np.array([[4.0, -1.0]] * 3)
    res = fit_structure(p, r, metric)
    assert res.pose.th == 0.0
    assert np.all(np.isfinite(res.residuals_m))


@pytest.mark.parametrize("metric", METRICS)
def test_robots_exactly_on_the_structure_give_zero_cost_and_no_nan(metric):
    g = Pose2(1.5, -2.0, 2.9)
    for p in (TRIANGLE, np.array([[0, 0], [1, 0], [2, 0], [3, 0.0]]), np.array([[0, 0], [0, 0], [1, 1.0]])):
        res = fit_structure(p, g.apply(p), metric)
        assert res.cost <= 1e-12
        assert pose_close(res.pose, g, 1e-9)
        assert np.all(np.isfinite(res.residuals_m))


@pytest.mark.parametrize("metric", METRICS)
def test_collinear_and_repeated_template_points_still_fit(metric):
    p = np.array([[0.0, 0.0], [1.0, 0.0], [2.0, 0.0], [2.0, 0.0]])
    r = Pose2(0.3, 0.4, -1.0).apply(p) + np.array([[0.01, 0.0], [0.0, -0.02], [0.03, 0.01], [-0.01, 0.0]])
    res = fit_structure(p, r, metric)
    assert np.isfinite(res.cost)
    x0 = fit_structure(p, r, "l2").pose.as_tuple()
    assert res.cost <= _powell(p, r, metric, x0) + 1e-12


# ---------------------------------------------------------------- determinism and result type


@pytest.mark.parametrize("metric", METRICS)
def test_the_same_inputs_give_bit_identical_fits(metric):
    p, r = noisy_case(7, 42, 0.1)
    w = np.linspace(0.5, 2.0, 7) if metric != "linf" else np.array([1.5, 1.5, 0.0, 1.5, 1.5, 1.5, 1.5])
    a = fit_structure(p, r, metric, w)
    b = fit_structure(p.copy(), r.copy(), metric, w.copy())
    assert a.pose.as_tuple() == b.pose.as_tuple()
    assert a.cost == b.cost
    assert a.cost_lower_bound == b.cost_lower_bound
    assert np.array_equal(a.residuals_m, b.residuals_m)


def test_the_result_is_frozen_and_its_residuals_read_only():
    res = fit_structure(TRIANGLE, TRIANGLE + 1.0, "linf")
    assert isinstance(res, FitResult)
    assert res.metric == "linf"
    with pytest.raises(dataclasses.FrozenInstanceError):
        res.cost = 1.0
    with pytest.raises(ValueError):
        res.residuals_m[0] = 1.0


def test_large_formations_fit_in_reasonable_time():
    rng = np.random.default_rng(0)
    p = rng.uniform(-10, 10, (1000, 2))
    r = Pose2(1.0, 2.0, 0.7).apply(p) + rng.normal(0.0, 0.1, (1000, 2))
    for metric in METRICS:
        res = fit_structure(p, r, metric)
        assert res.cost_lower_bound <= res.cost <= res.cost_lower_bound + 1e-9


# ---------------------------------------------------------------- errors


@pytest.mark.parametrize(
    "template, positions",
    [
        (np.zeros((3, 3)), np.zeros((3, 2))),
        (np.zeros((3, 2)), np.zeros((4, 2))),
        (np.zeros(6), np.zeros(6)),
        (np.zeros((3, 2, 1)), np.zeros((3, 2))),
        ([["a", "b"]], [[1.0, 2.0]]),
        (np.zeros((2, 2), dtype=complex), np.zeros((2, 2))),
        ([[1.0, object()]], [[1.0, 2.0]]),
    ],
)
def test_bad_shapes_and_non_numeric_input_are_shape_errors(template, positions):
    with pytest.raises(ShapeError):
        fit_structure(template, positions)
    with pytest.raises(ShapeError):
        structure_cost(template, positions, Pose2(0, 0, 0), "l2")


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
def test_nan_and_infinity_are_non_finite_errors(bad):
    p = TRIANGLE.copy()
    r = TRIANGLE.copy()
    r[1, 0] = bad
    with pytest.raises(NonFiniteError):
        fit_structure(p, r)
    with pytest.raises(NonFiniteError):
        fit_structure(r, p)
    with pytest.raises(NonFiniteError):
        fit_structure(p, p, weights=[1.0, bad, 1.0])


@pytest.mark.parametrize("metric", ["L2", "l3", "max", "", None, 2])
def test_an_unknown_metric_is_an_unknown_metric_error(metric):
    with pytest.raises(UnknownMetricError):
        fit_structure(TRIANGLE, TRIANGLE, metric)
    with pytest.raises(UnknownMetricError):
        structure_cost(TRIANGLE, TRIANGLE, Pose2(0, 0, 0), metric)


@pytest.mark.parametrize(
    "weights",
    [[1.0, -1.0, 1.0], [0.0, 0.0, 0.0], [1.0, 1.0], [[1.0, 1.0, 1.0]], ["a", "b", "c"], [True, True, True]],
)
def test_bad_weights_are_weight_errors(weights):
    with pytest.raises(WeightError):
        fit_structure(TRIANGLE, TRIANGLE, "l1", weights)


def test_every_error_is_a_value_error():
    for exc in (ShapeError, NonFiniteError, UnknownMetricError, WeightError):
        assert issubclass(exc, VsfleetValueError)
        assert issubclass(exc, ValueError)


@pytest.mark.parametrize("seed", range(12))
def test_the_linf_triangle_guesses_hold_the_certified_optimum(seed):
    from vsfleet.fit import certify, minimax, procrustes

    rng = np.random.default_rng(seed)
    p = TRIANGLE * rng.uniform(0.5, 3.0)
    r = Pose2(*rng.uniform(-3.0, 3.0, 2), rng.uniform(-math.pi, math.pi)).apply(p)
    r = r + rng.normal(0.0, (0.01, 0.05, 0.3)[seed % 3], r.shape)
    prob = certify.Problem(p, r, None)
    guesses = minimax.guesses(prob, procrustes.rotation(prob))
    res = fit_structure(p, r, "linf")
    assert res.cost - res.cost_lower_bound <= CERT_TOL
    assert min(abs(math.remainder(g - res.pose.th, 2.0 * math.pi)) for g in guesses) <= 1e-7
    assert minimax.guesses(certify.Problem(np.vstack([p, p[:1]]), np.vstack([r, r[:1]]), None), 0.0) == []


@pytest.mark.parametrize("n", [4, 10, 30, 100])
def test_the_linf_descent_from_the_l2_rotation_lands_on_the_certified_optimum(n):
    from vsfleet.fit import certify, minimax, procrustes

    landed, once = 0, 0
    for seed in range(10):
        rng = np.random.default_rng(seed)
        p = rng.uniform(-1.0, 1.0, (n, 2))
        r = Pose2(*rng.uniform(-3, 3, 2), rng.uniform(-math.pi, math.pi)).apply(p) + rng.normal(0, 0.05, (n, 2))
        prob, calls = certify.Problem(p, r, None), []
        res = fit_structure(p, r, "linf")
        with np.errstate(all="ignore"):
            th, t0, found = minimax.descend(prob, procrustes.rotation(prob))
            if found:  # as fit_structure runs it: a lean first batch around the local minimum
                certify.search(prob, lambda *a: calls.append(1) or minimax.evaluate(*a), th, [th], minimax.SPLIT,
                               t0=t0, lean=True, refine=minimax.kinks)
        assert res.cost - res.cost_lower_bound <= CERT_TOL
        if found and abs(math.remainder(th - res.pose.th, 2.0 * math.pi)) <= 2e-9:
            landed, once = landed + 1, once + (len(calls) == 1)
    assert landed >= 9 and once >= landed - 1  # a landed hint certifies in the first batch


@pytest.mark.parametrize("seed", [0, 2, 3])  # smooth optima (seed 1's has a robot on t: F has a kink there)
def test_the_l1_newton_start_lands_on_the_certified_rotation_and_a_bad_start_only_costs_rounds(seed):
    from vsfleet.fit import certify, median, procrustes

    rng = np.random.default_rng(seed)
    p = rng.uniform(-1.0, 1.0, (200, 2))
    r = Pose2(*rng.uniform(-3.0, 3.0, 2), rng.uniform(-math.pi, math.pi)).apply(p) + rng.normal(0, 0.05, p.shape)
    prob = certify.Problem(p, r, None)
    th0 = procrustes.rotation(prob)
    res = fit_structure(p, r, "l1")
    th, (tx, ty), converged = median.newton(prob, th0)
    assert converged and abs(math.remainder(th - res.pose.th, 2.0 * math.pi)) <= 1e-12
    assert not median.newton(prob, th0, iters=1)[2]  # one step from the l2 rotation is not enough
    # from far away (a maximum of f in th, then a slope) Newton gives up; a lean search from there still certifies
    for start in (th0 + math.pi, th0 + 0.5):
        th, t0, converged = median.newton(prob, start)
        assert not converged
        with np.errstate(all="ignore"):  # as fit_structure runs it
            th, tx, ty, lower = certify.search(prob, median.evaluate, th, t0=t0, lean=True)
        cost = structure_cost(p, r, prob.pose(th, tx, ty), "l1")
        assert abs(cost - res.cost) <= CERT_TOL and cost - lower <= CERT_TOL


@pytest.mark.parametrize("n, seed", [(10, s) for s in range(8)] + [(40, s) for s in range(4)])
def test_the_linf_basis_hints_land_on_the_certified_optimum(n, seed):
    from vsfleet.fit import certify, minimax, procrustes

    rng = np.random.default_rng(seed)
    p = rng.uniform(-1.0, 1.0, (n, 2))
    r = Pose2(*rng.uniform(-3, 3, 2), rng.uniform(-math.pi, math.pi)).apply(p) + rng.normal(0, 0.05, (n, 2))
    prob = certify.Problem(p, r, None)
    hints = []

    def record(*args):
        out = minimax.kinks(*args)
        hints.extend(out)
        return out

    with np.errstate(all="ignore"):
        th, tx, ty, lower = certify.search(prob, minimax.evaluate, procrustes.rotation(prob), refine=record)
    cost = structure_cost(p, r, prob.pose(th, tx, ty), "linf")
    assert cost - lower <= CERT_TOL
    # a kink (two bases' radii equal) or a basis's stationary point, to within the first ladder step
    assert min(abs(math.remainder(h - th, 2.0 * math.pi)) for h in hints) <= 2e-9
