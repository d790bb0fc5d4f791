"""The compiled fit (vsfleet._core, vs_fit.c) against the numpy reference (fit_structure_reference).

Equality: costs within 1e-9 [weighted m], certified gaps, the same discrete outcome (which robots
are used, the closed-form branches), and poses within 1e-9 m / rad wherever the optimum is sharp.
Where it is flat to rounding (a smooth l1 or linf minimum pins th only to about sqrt(eps): the
costs at th* and th* +- 3e-8 differ in the last bit, and the two implementations, whose sines and
sums differ by an ulp, pick different angles of the same ladder) the poses may differ by up to
~1e-7 rad; there the test checks that the core's pose is optimal under the reference's own cost
(within the certified tolerance) instead.  The numpy reference is not run on the pathological
inputs (near-coincident robots): it has no work cap and can run out of memory there.
"""

import math

import numpy as np
import pytest
from hypothesis import example, HealthCheck, given, settings
from hypothesis import strategies as st

from vsfleet import _core
from vsfleet.coreconst import FIT_MAX_ROUNDS as MAX_ROUNDS, METRIC_CODES as CODES, METRICS
from vsfleet.errors import NonFiniteError, ShapeError, UnknownMetricError, VsfleetValueError, WeightError
from vsfleet.fit import (CERT_TOL, fit_structure, fit_structure_reference, structure_cost,
                         structure_cost_reference)
from vsfleet.geometry import Pose2

EPS = np.finfo(float).eps
SETTINGS = dict(deadline=None, suppress_health_check=[HealthCheck.too_slow])


def _tol(p, r, cost):
    """The certified gap the search guarantees: CERT_TOL, or the rounding allowance of a huge problem
    (128 eps bound (max |K| + 1), with |K| <= about n * bound for these inputs)."""
    P, Q = p - p.mean(axis=0), r - r.mean(axis=0)
    bound = np.hypot(*Q.T).max() + np.hypot(*P.T).max()
    return max(CERT_TOL, 256.0 * EPS * bound * (len(p) * bound + cost + 1.0)) + 1e-12


def _angle(a, b):
    return abs(math.remainder(a - b, 2.0 * math.pi))


def _case(seed, n, scale=1.0, noise=0.05, offset=0.0):
    rng = np.random.default_rng(seed)
    p = rng.uniform(-1.0, 1.0, (n, 2)) * scale
    g = Pose2(*(rng.uniform(-3, 3, 2) * scale + offset), rng.uniform(-math.pi, math.pi))
    return p, g.apply(p) + rng.normal(0.0, noise * scale, (n, 2)), rng


def assert_agrees_with_the_reference(p, r, metric, w=None):
    core, ref = fit_structure(p, r, metric, w), fit_structure_reference(p, r, metric, w)
    tol = _tol(p, r, ref.cost)
    assert core.metric == ref.metric
    assert core.residuals_m.shape == ref.residuals_m.shape and not core.residuals_m.flags.writeable
    assert abs(core.cost - ref.cost) <= max(1e-9, tol)
    assert core.cost - core.cost_lower_bound <= tol  # certified
    assert core.cost_lower_bound <= ref.cost + max(1e-9, tol)  # never above the reference's optimum
    assert core.cost == structure_cost(p, r, core.pose, metric, w)
    dpose = max(abs(core.pose.x - ref.pose.x), abs(core.pose.y - ref.pose.y), _angle(core.pose.th, ref.pose.th))
    if metric == "l2" or dpose <= 1e-9:
        pose_tol = 1e-9 * max(1.0, np.abs(r).max())
        assert dpose <= pose_tol
        # two poses pose_tol apart move a residual by up to pose_tol (sqrt 2 + |p_i|): the translation and
        # the rotation's lever arm (a linf optimum 1e-9 apart moved residuals 2.09e-9, n = 67, |p| <= 1.41)
        lever = math.sqrt(2.0) + float(np.hypot(*p.T).max())
        assert np.allclose(core.residuals_m, ref.residuals_m, rtol=0.0, atol=pose_tol * lever)
    else:  # a flat optimum: the core's pose is optimal under the reference's own cost
        assert structure_cost_reference(p, r, core.pose, metric, w) <= ref.cost_lower_bound + max(1e-9, 2 * tol)
    return core, ref


@settings(max_examples=200, **SETTINGS)
@given(metric=st.sampled_from(["l1", "l2", "linf"]),
       n=st.one_of(st.integers(1, 12), st.integers(13, 100)),
       seed=st.integers(0, 2**32 - 1),
       noise=st.sampled_from([0.0, 1e-3, 0.05, 0.4, 3.0]),
       scale=st.sampled_from([1.0, 1e-4, 10.0]),
       weighted=st.sampled_from(["none", "positive", "zeros"]))
@example(metric="linf", n=67, seed=19138854, noise=0.05, scale=1.0, weighted="zeros")  # poses 1e-9 apart
def test_the_core_fit_agrees_with_the_reference_on_random_formations(metric, n, seed, noise, scale, weighted):
    p, r, rng = _case(seed, n, scale, noise)
    w = None
    if weighted != "none":
        w = rng.uniform(0.2, 3.0, n) if metric != "linf" else np.full(n, 2.5)
        if weighted == "zeros":
            w[rng.random(n) < 0.3] = 0.0
            w[rng.integers(n)] = 1.0 if metric != "linf" else 2.5
    assert_agrees_with_the_reference(p, r, metric, w)


@pytest.mark.parametrize("metric", ["l1", "l2", "linf"])
@pytest.mark.parametrize("n", [3, 4, 10, 100])
def test_far_off_and_tiny_formations_agree_with_the_reference(metric, n):
    for seed in range(3):
        assert_agrees_with_the_reference(*_case(seed, n, offset=1e4)[:2], metric)  # 1e4 m from the origin
        assert_agrees_with_the_reference(*_case(seed, n, scale=1e-4)[:2], metric)  # 0.1 mm formations


@pytest.mark.parametrize("metric", ["l1", "l2", "linf"])
def test_collinear_unrelated_and_symmetric_inputs_agree_with_the_reference(metric):
    rng = np.random.default_rng(7)
    for n in (3, 5, 12, 40):
        t = np.linspace(-1.0, 1.0, n)
        line = np.stack([t, 0.0 * t], axis=1)
        g = Pose2(0.3, -0.2, 1.1)
        assert_agrees_with_the_reference(line, g.apply(line) + rng.normal(0, 0.05, (n, 2)), metric)
        assert_agrees_with_the_reference(line, rng.uniform(-1, 1, (n, 2)), metric)  # collinear template only
        assert_agrees_with_the_reference(rng.uniform(-1, 1, (n, 2)), rng.uniform(-1, 1, (n, 2)), metric)  # unrelated
        ring = np.stack([np.cos(2 * np.pi * np.arange(n) / n), np.sin(2 * np.pi * np.arange(n) / n)], axis=1)
        assert_agrees_with_the_reference(ring, 1.1 * ring, metric)  # n-fold symmetric: tied optima


def _awkward(seed):
    """(name, template, positions) the search finds hard: flat f, many kinks, huge spreads."""
    rng = np.random.default_rng(seed)
    for n in (3, 4, 7, 12, 40, 150):
        p = rng.uniform(-1, 1, (n, 2))
        r = Pose2(*rng.uniform(-3, 3, 2), rng.uniform(-math.pi, math.pi)).apply(p) + rng.normal(0, 0.05, (n, 2))
        near = r.copy()
        near[1:] = near[0] + rng.normal(0, 1e-12, (n - 1, 2))
        yield "near-coincident robots", p, near
        tpl = p.copy()
        tpl[1:] = tpl[0] + rng.normal(0, 1e-13, (n - 1, 2))
        yield "near-coincident template", tpl, r
        half = r.copy()
        half[: n // 2 + 1] = half[0] + rng.normal(0, 1e-12, (n // 2 + 1, 2))
        yield "half the robots near-coincident", p, half
        t = np.linspace(-1, 1, n)
        yield "collinear template, scattered robots", np.stack([t, 0 * t], axis=1), rng.uniform(-1, 1, (n, 2))
        yield "unrelated poses", p, rng.uniform(-1, 1, (n, 2))
        yield "far-off robots", p, r + 1e4
        yield "tiny formation", p * 1e-4, r * 1e-4
        yield "huge noise", p, r + rng.normal(0, 100, (n, 2))


@pytest.mark.parametrize("metric", ["l1", "linf"])
def test_awkward_inputs_stay_under_the_work_cap_and_certify(metric):
    for seed in range(2):
        for name, p, r in _awkward(seed):
            x, y, th, cost, lower, rounds = _core.fit(np.ascontiguousarray(p), np.ascontiguousarray(r), None,
                                                    CODES[metric], None)
            assert 1 <= rounds <= MAX_ROUNDS, name
            assert lower <= cost, name
            assert cost - lower <= max(1e-9, _tol(p, r, cost)), (name, len(p), cost - lower)
            assert cost == structure_cost(p, r, (x, y, th), metric), name


def test_the_same_input_twice_gives_bit_identical_fits():
    for metric in ("l1", "l2", "linf"):
        for n in (1, 2, 3, 11, 60, 200):
            p, r, rng = _case(n, n)
            w = rng.uniform(0.5, 2.0, n) if metric != "linf" else None
            a, b = fit_structure(p, r, metric, w), fit_structure(p.copy(), r.copy(), metric, w)
            assert a.pose.as_tuple() == b.pose.as_tuple()
            assert (a.cost, a.cost_lower_bound) == (b.cost, b.cost_lower_bound)
            assert np.array_equal(a.residuals_m, b.residuals_m)
            assert _core.fit(p, r, w, CODES[metric], None) == _core.fit(p, r, w, CODES[metric], None)


@pytest.mark.parametrize("metric", ["l1", "l2", "linf"])
def test_degenerate_cases_take_the_reference_branches(metric):
    one = fit_structure([[0.3, -0.1]], [[2.3, 4.9]], metric)
    assert one.pose.th == 0.0 and one.cost == pytest.approx(0.0, abs=1e-15)
    assert _core.fit(np.array([[0.3, -0.1]]), np.array([[2.3, 4.9]]), None, CODES[metric], None)[5] == 0
    p2, r2 = np.array([[0.0, 0.0], [1.0, 0.0]]), np.array([[1.0, 1.0], [1.0, 2.5]])
    two = assert_agrees_with_the_reference(p2, r2, metric)[0]
    assert two.pose.th == pytest.approx(math.pi / 2, abs=1e-12)
    same = np.array([[0.5, 0.5]] * 4)
    rob = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 2.0], [3.0, 1.0]])
    for p, r in ((same, rob), (rob, same)):  # all template points or all robots coincide: th = 0
        core = assert_agrees_with_the_reference(p, r, metric)[0]
        assert core.pose.th == 0.0
    on = _case(3, 6, noise=0.0)[:2]  # robots exactly on the structure
    core = assert_agrees_with_the_reference(*on, metric)[0]
    assert core.cost <= 1e-12 and np.all(np.isfinite(core.residuals_m))


@pytest.mark.parametrize("metric", ["l1", "l2", "linf"])
def test_zero_weights_drop_robots_as_in_the_reference(metric):
    p, r, rng = _case(3, 8)
    r[2] += 100.0  # an outlier, weighted out
    w = np.ones(8)
    w[2] = 0.0
    core, _ = assert_agrees_with_the_reference(p, r, metric, w)
    assert core.residuals_m[2] > 50.0
    sub = fit_structure(np.delete(p, 2, axis=0), np.delete(r, 2, axis=0), metric)
    assert core.cost == pytest.approx(sub.cost, abs=1e-9)
    only = np.zeros(8)
    only[5] = 1.0  # one robot left: it sits on its point
    assert fit_structure(p, r, metric, only).residuals_m[5] == pytest.approx(0.0, abs=1e-12)


@pytest.mark.parametrize("fit", [fit_structure, fit_structure_reference])
def test_bad_inputs_raise_the_typed_errors(fit):
    tri = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
    for bad in (math.nan, math.inf, -math.inf, 1e300):
        r = tri.copy()
        r[1, 0] = bad
        with pytest.raises(NonFiniteError):
            fit(tri, r, "l1")
        with pytest.raises(NonFiniteError):
            fit(r, tri, "linf")
        with pytest.raises(NonFiniteError):
            fit(tri, tri, "l2", [1.0, bad, 1.0])
    for template, positions in (([], []), (tri, tri[:2]), (tri[:, :1], tri[:, :1]), ("abc", tri), (tri, [[1j, 0]] * 3)):
        with pytest.raises(ShapeError):
            fit(template, positions, "l2")
    for metric in ("l3", None, 2, "L1"):
        with pytest.raises(UnknownMetricError):
            fit(tri, tri, metric)
    for weights in ([1.0, -1.0, 1.0], [0.0, 0.0, 0.0], [1.0, 1.0], [[1.0, 1.0, 1.0]]):
        with pytest.raises(WeightError):
            fit(tri, tri, "l1", weights)
    with pytest.raises(WeightError):
        fit(tri, tri, "linf", [1.0, 2.0, 1.0])  # linf: 0/equal weights only
    for e in (NonFiniteError, ShapeError, UnknownMetricError, WeightError):
        assert issubclass(e, ValueError)


def test_the_binding_refuses_bad_buffers_with_typed_errors():
    tri = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
    with pytest.raises(VsfleetValueError):
        _core.fit(tri, tri, None, len(METRICS), None)  # unknown metric code
    with pytest.raises(VsfleetValueError):
        _core.fit(np.zeros((0, 2)), np.zeros((0, 2)), None, CODES["l2"], None)  # n = 0
    with pytest.raises(NonFiniteError):
        _core.fit(tri, np.where(tri == 1.0, np.nan, tri), None, CODES["l1"], None)
    with pytest.raises(VsfleetValueError):
        _core.fit(tri, tri, np.array([1.0, 2.0, 1.0]), CODES["linf"], None)  # linf, unequal weights
    with pytest.raises(ValueError):
        _core.fit(tri, tri[:2], None, CODES["l2"], None)  # lengths differ
    with pytest.raises(TypeError):
        _core.fit(tri.astype(np.float32), tri, None, CODES["l2"], None)
    with pytest.raises(NonFiniteError):
        _core.fit_cost(tri, tri, None, CODES["l1"], math.nan, 0.0, 0.0)


def test_structure_cost_matches_the_reference_and_the_fit():
    p, r, rng = _case(11, 9)
    w = rng.uniform(0.2, 2.0, 9)
    for metric in ("l1", "l2", "linf"):
        ww = None if metric == "linf" else w
        pose = (0.2, -0.4, 2.5)
        assert structure_cost(p, r, pose, metric, ww) == pytest.approx(
            structure_cost_reference(p, r, pose, metric, ww), rel=1e-14)
        res = fit_structure(p, r, metric, ww)
        assert res.cost == structure_cost(p, r, res.pose, metric, ww)
        assert res.residuals_m == pytest.approx(fit_structure_reference(p, r, metric, ww).residuals_m, abs=1e-7)


def test_non_array_inputs_take_the_validating_path():
    tri = [[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]]
    moved = [[1.0, 1.0], [1.0, 2.0], [0.0, 1.0]]
    for a, b in ((tri, moved), (np.array(tri, dtype=np.float32), np.array(moved)), (np.array(tri)[:, ::-1][:, ::-1],
                                                                                       np.asfortranarray(moved))):
        res = fit_structure(a, b, "l2")
        assert res.pose.th == pytest.approx(math.pi / 2, abs=1e-12)
        assert res.cost == pytest.approx(0.0, abs=1e-12)
