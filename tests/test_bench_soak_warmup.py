"""bench/soak.py's RSS growth after the warm-up (issue 30): reported beside the raw growth, never instead of it."""

import pytest

from bench import soak


def _inst(name, index, started, series, last_at=None, **kw):
    """An instance with readings series [(t, VmRSS, RssAnon, RssShmem)]; first = the reading 30 s after it started."""
    first = next(p for p in series if p[0] >= started + 30.0)
    last = series[-1]
    return {"name": name, "index": index, "started": started, "ended": None, "first_rss": first[1],
            "first_at": first[0], "first_anon": first[2], "last_rss": last[1], "last_anon": last[2],
            "last_at": last[0] if last_at is None else last_at, "series": series, **kw}


def _ramp(started, until, rise_until_s, rise_mib, base=50.0, step=5.0):
    """RSS rising by rise_mib over the first rise_until_s after started, flat after, sampled every step s."""
    out, t = [], started
    while t <= until:
        r = base + rise_mib * min(1.0, (t - started) / rise_until_s)
        out.append((t, r, r - 30.0, 0.0))
        t += step
    return out


def test_the_growth_after_the_warmup_starts_120_s_after_the_process_and_the_raw_growth_stays():
    inst = _inst("agent-r1", 1, 0.0, _ramp(0.0, 360.0, 90.0, 4.0))
    rows = soak.rss_rows([inst])
    (r,) = rows
    assert r["growth_mib"] == pytest.approx(4.0 * 60.0 / 90.0)   # from 30 s: the rise after it
    assert not r["holds"]
    assert r["warm_growth_mib"] == pytest.approx(0.0) and r["warm_anon_growth_mib"] == pytest.approx(0.0)
    assert r["warm_holds"] and r["warm_instances"] == 1
    got = {t["target"]: t for t in soak.targets({"rss": rows, "crashes": [], "agreement": {"outside": {
        "frames": 1, "identical": 1}}, "contacts": {"frames": 0, "truth_frames": 1, "min_gap_m": 1.0}})}
    assert not got["RSS growth <= 2 MiB per process"]["holds"]              # the raw figure still decides it
    assert got["(the same, after a 120 s warm-up)"]["holds"]


def test_an_instance_too_short_for_the_warmup_has_no_such_figure_and_the_largest_is_over_the_others():
    short = _inst("agent-r1", 2, 400.0, _ramp(400.0, 560.0, 60.0, 1.0))          # 160 s: < 120 + 60
    longer = _inst("agent-r1", 1, 0.0, [(t, 50.0 + 0.01 * t, 20.0 + 0.01 * t, 0.0) for t in range(0, 361, 5)])
    (r,) = soak.rss_rows([longer, short])
    assert r["warm_growth_mib"] is None                      # the newest instance: too short
    assert r["max_warm_growth_mib"] == pytest.approx(0.01 * (360 - 120))
    assert r["warm_instances"] == 1 and r["instances"] == 2
    assert soak.after_warmup(short) is None


def test_the_markdown_shows_both_growths():
    inst = _inst("sim", 1, 0.0, _ramp(0.0, 600.0, 100.0, 3.0))
    rep_rows = soak.rss_rows([inst])
    text = "\n".join(f"{r['growth_mib']:+.2f} {soak._mib(r['warm_growth_mib'], none='-')}{soak._of(r)}" for r in rep_rows)
    assert text == "+2.10 +0.00 (1 of 1)"
