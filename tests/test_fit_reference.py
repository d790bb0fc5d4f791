"""The certified fits against brute-force references (independent code: dense angle grid, a
crude inner solve per angle, then Nelder-Mead in (x, y, th) from the best angles)."""

import math

import numpy as np
import pytest

from vsfleet import _core
from vsfleet.coreconst import METRIC_CODES
from vsfleet.fit import CERT_TOL, _as_pose, _contiguous, _validate, fit_structure, structure_cost
from vsfleet.fit import certify, median, minimax
from vsfleet.errors import NonFiniteError, ShapeError
from vsfleet.geometry import Pose2

GRID = 721  # reference angles: memory GRID * n floats per array (<= 0.6 MB at n = 100)


def _inner(q, metric, iters=200):
    """Approximate inner optimum for every angle: Weiszfeld (l1), Badoiu-Clarkson (linf).

    On x and y apart (hypot rather than norm over a last axis of 2: a third of the time)."""
    qx, qy = q[..., 0], q[..., 1]
    tx, ty = qx.mean(axis=1), qy.mean(axis=1)
    rows = np.arange(len(q))
    for k in range(iters):
        d = np.hypot(qx - tx[:, None], qy - ty[:, None])
        if metric == "l1":
            iw = 1.0 / np.maximum(d, 1e-12)
            w = iw.sum(axis=1)
            tx, ty = (iw * qx).sum(axis=1) / w, (iw * qy).sum(axis=1) / w
        else:
            far = np.argmax(d, axis=1)
            tx, ty = tx + (qx[rows, far] - tx) / (k + 2), ty + (qy[rows, far] - ty) / (k + 2)
    d = np.hypot(qx - tx[:, None], qy - ty[:, None])
    return d.sum(axis=1) if metric == "l1" else d.max(axis=1)


def reference(p, r, metric, starts=4):
    """An upper bound of the optimum found by brute force (never by vsfleet.fit's solvers)."""
    from scipy.optimize import minimize  # noqa: PLC0415 - here: scipy.optimize is 0.1-0.3 s of each worker's collection
    th = np.linspace(-math.pi, math.pi, GRID, endpoint=False)
    c, s = np.cos(th)[:, None], np.sin(th)[:, None]
    q = np.stack([r[:, 0] - (c * p[:, 0] - s * p[:, 1]), r[:, 1] - (s * p[:, 0] + c * p[:, 1])], axis=2)
    f = _inner(q, metric)
    # structure_cost(p, r, x, metric), its checks of p, r and metric made once instead of on each of Nelder-Mead's
    # ~300 000 calls (3/4 of this reference's time went into them): the same call into the core, the same bits
    pc, rc, _ = _contiguous(*_validate(p, r, metric, None))
    code = METRIC_CODES[metric]

    def cost(x):
        pose = _as_pose((x[0], x[1], x[2]))
        return _core.fit_cost(pc, rc, None, code, pose.x, pose.y, pose.th)

    best = math.inf
    for k in np.argsort(f)[:starts]:
        t = q[k].mean(axis=0)
        x0 = [t[0], t[1], th[k]]
        res = minimize(cost, x0, method="Nelder-Mead", options={"xatol": 1e-13, "fatol": 1e-15, "maxiter": 4000})
        best = min(best, res.fun, float(f[k]))
    return best


def _check(p, r, metric):
    res = fit_structure(p, r, metric)
    ref = reference(p, r, metric)
    assert res.cost <= ref + CERT_TOL  # within the certified gap of brute force
    assert res.cost_lower_bound <= ref + 1e-12  # the certificate never overshoots
    assert res.cost - res.cost_lower_bound <= CERT_TOL
    assert res.cost == structure_cost(p, r, res.pose, metric)
    return res


def _case(n, seed, noise=0.05):
    rng = np.random.default_rng(seed)
    p = rng.uniform(-1.0, 1.0, (n, 2))
    r = Pose2(*rng.uniform(-3, 3, 2), rng.uniform(-math.pi, math.pi)).apply(p) + rng.normal(0, noise, (n, 2))
    return p, r


@pytest.mark.parametrize("metric", ["l1", "linf"])
@pytest.mark.parametrize("n", [*range(3, 13), 50, 100])
def test_noisy_fits_match_the_brute_force_reference(n, metric):
    for seed in range(2 if n <= 12 else 1):
        _check(*_case(n, 100 * n + seed, noise=0.05 if seed == 0 else 0.4), metric)


@pytest.mark.parametrize("metric", ["l1", "linf"])
def test_ties_collinear_and_coincident_points_match_the_reference(metric):
    line = np.array([[0.0, 0.0], [1.0, 0.0], [2.0, 0.0], [3.0, 0.0], [3.0, 0.0]])
    g = Pose2(0.5, -1.0, 2.0)
    rng = np.random.default_rng(5)
    # collinear template with a repeated point, noisy robots
    _check(line, g.apply(line) + rng.normal(0, 0.05, line.shape), metric)
    # collinear robots, planar template
    p = np.array([[0.0, 0.0], [1.0, 0.2], [0.3, 1.0], [-0.4, 0.5]])
    _check(p, np.array([[0.0, 0.0], [1.0, 0.0], [2.0, 0.0], [3.0, 0.0]]), metric)
    # two coincident robots, the rest noisy; cocircular robots (many tied residuals)
    r = g.apply(p) + rng.normal(0, 0.1, p.shape)
    r[1] = r[0]
    _check(p, r, metric)
    k = np.arange(8) * (2 * math.pi / 8)
    ring = np.stack([np.cos(k), np.sin(k)], axis=1)
    _check(ring, 1.3 * ring, metric)


@pytest.mark.parametrize("metric", ["l1", "l2", "linf"])
@pytest.mark.parametrize("n", [3, 6, 12, 50])
def test_symmetric_noise_free_input_is_recovered_exactly(n, metric):
    k = np.arange(n) * (2 * math.pi / n)
    ring = np.stack([np.cos(k), np.sin(k)], axis=1)
    g = Pose2(-2.0, 1.0, 0.7)
    res = fit_structure(ring, g.apply(ring), metric)
    assert res.cost <= 1e-12
    assert abs(math.remainder(res.pose.th - g.th, 2 * math.pi)) <= 1e-9
    assert res.cost_lower_bound <= res.cost


@pytest.mark.parametrize("metric", ["l1", "l2", "linf"])
@pytest.mark.parametrize("n", [3, 11, 60, 400])
def test_the_same_input_gives_bit_identical_output(n, metric):
    p, r = _case(n, n)
    a, b = fit_structure(p, r, metric), fit_structure(p.copy(), r.copy(), metric)
    assert a.pose.as_tuple() == b.pose.as_tuple()
    assert (a.cost, a.cost_lower_bound) == (b.cost, b.cost_lower_bound)
    assert a.residuals_m.tobytes() == b.residuals_m.tobytes()


def test_the_minorants_are_below_the_cost_at_every_angle():
    p, r = _case(9, 3, noise=0.3)
    prob = certify.Problem(p, r, None)
    th = np.linspace(-math.pi, math.pi, 50, endpoint=False)
    c, s = np.cos(th), np.sin(th)
    for ev in (median.evaluate, minimax.evaluate):
        with np.errstate(all="ignore"):  # as fit_structure runs them
            f, tx, ty, K, A, B = ev(prob, c, s, np.zeros(50), np.zeros(50), np.zeros(50, bool))[:6]
        m = K[:, None] - A[:, None] * c - B[:, None] * s  # minorant of angle i at angle j
        assert (m <= f[None, :] + 1e-12).all()
        assert np.abs(np.diag(m) - f).max() <= 1e-9  # tight where it was made


def test_the_cell_bound_is_the_minimum_over_the_cell_of_the_larger_minorant():
    rng = np.random.default_rng(1)
    Ka, Aa, Ba, Kb, Ab, Bb = rng.normal(0, 1, (6, 200))
    a = rng.uniform(-math.pi, math.pi, 200)
    b = a + rng.uniform(1e-3, 2.5, 200)
    lb, bc, bs = certify.cell_bounds(np.cos(a), np.sin(a), np.cos(b), np.sin(b), Ka, Aa, Ba, Kb, Ab, Bb)
    t = a[:, None] + (b - a)[:, None] * np.linspace(0, 1, 20001)
    cos_t, sin_t = np.cos(t), np.sin(t)   # each once for both minorants (4 M angles)
    v = np.maximum(Ka[:, None] - Aa[:, None] * cos_t - Ba[:, None] * sin_t,
                   Kb[:, None] - Ab[:, None] * cos_t - Bb[:, None] * sin_t)
    brute = np.maximum(v.min(axis=1), 0.0)
    assert (lb <= brute + 1e-12).all()
    assert np.abs(lb - brute).max() <= 2e-4  # the brute grid step is 1.25e-4 rad


def test_an_inner_solve_cut_short_still_gives_a_valid_minorant():
    p, r = _case(30, 8, noise=0.2)
    prob = certify.Problem(p, r, None)
    th = np.linspace(-math.pi, math.pi, 12, endpoint=False)
    c, s = np.cos(th), np.sin(th)
    with np.errstate(all="ignore"):  # as fit_structure runs them
        exact = median.evaluate(prob, c, s, np.zeros(12), np.zeros(12), np.zeros(12, bool))
        short = median.evaluate(prob, c, s, np.zeros(12), np.zeros(12), np.zeros(12, bool), iters=1)
    for f, K, A, B in ((exact[0], *exact[3:]), (short[0], *short[3:])):
        m = K[:, None] - A[:, None] * c - B[:, None] * s
        assert (m <= exact[0][None, :] + 1e-12).all()
    assert (short[0] >= exact[0] - 1e-12).all()  # a true cost at its translation: never below f


@pytest.mark.parametrize("max_rounds", [1, 60])
def test_a_search_that_cannot_certify_stops_and_states_its_gap(max_rounds):
    p, r = _case(7, 4, noise=0.2)
    prob = certify.Problem(p, r, None)
    th0 = fit_structure(p, r, "l2").pose.th
    for ev in (median.evaluate, minimax.evaluate):
        with np.errstate(all="ignore"):  # as fit_structure runs it
            th, tx, ty, lower = certify.search(prob, ev, th0, tol=0.0, max_rounds=max_rounds)
        res = fit_structure(p, r, "l1" if ev is median.evaluate else "linf")
        assert lower <= res.cost_lower_bound + 1e-12 or lower <= res.cost
        cost = structure_cost(p, r, prob.pose(th, tx, ty), "l1" if ev is median.evaluate else "linf")
        assert lower <= cost
        assert cost <= res.cost + (1.0 if max_rounds == 1 else CERT_TOL)


def test_structure_cost_rejects_a_malformed_pose():
    p = np.array([[0.0, 0.0], [1.0, 0.0]])
    with pytest.raises(ShapeError):
        structure_cost(p, p, ("a", 0.0, 0.0), "l2")
    with pytest.raises(ShapeError):
        structure_cost(p, p, (0.0, 0.0), "l2")
    with pytest.raises(NonFiniteError):
        structure_cost(p, p, (math.nan, 0.0, 0.0), "l2")


def test_the_search_stops_when_no_uncertified_cell_can_be_split():
    def loose(prob, c, s, tx0, ty0, rough):  # f = 1 everywhere, a flat minorant 0.5 below it
        m = len(c)
        return np.ones(m), np.zeros(m), np.zeros(m), np.full(m, 0.5), np.zeros(m), np.zeros(m)

    prob = certify.Problem(np.array([[0.0, 0.0], [1.0, 0.0]]), np.array([[0.0, 0.0], [0.0, 1.0]]), None)
    with np.errstate(all="ignore"):  # as fit_structure runs it
        th, tx, ty, lower = certify.search(prob, loose, 0.3)
    assert lower == pytest.approx(0.5, abs=1e-12)  # the gap is stated, not hidden


@pytest.mark.parametrize("metric", ["l1", "linf"])
@pytest.mark.parametrize("n", [4, 5, 8, 13])
def test_noise_free_robots_with_one_moved_onto_another_are_certified(n, metric):
    # every q_i but one coincides at the optimum (to rounding): the l1 median sits on a cluster
    rng = np.random.default_rng(n)
    p = rng.uniform(-1.0, 1.0, (n, 2))
    r = Pose2(1.0, -2.0, 2.5).apply(p)
    r[2] = r[0]
    for w in (None, rng.uniform(0.1, 3.0, n)) if metric == "l1" else (None,):
        res = fit_structure(p, r, metric, w)
        assert res.cost - res.cost_lower_bound <= CERT_TOL
        if w is None:
            assert res.cost <= reference(p, r, metric) + CERT_TOL
