"""Two trackers publish frames of the same fleet at once, with different noise and latency (issue 30): every
agent follows the same one, so the copies stay bit-identical, and each agent says which it follows."""

from __future__ import annotations

import threading
import time

import pytest

from vsfleet import frames
from vsfleet.wire import WireError, decode_frame

from .conftest import at_goal, start_fleet

pytestmark = pytest.mark.integration


# cam2 silent this long before a frame lets sim's frame be run (the agent's default max_age_s)
MAX_AGE_S = frames.MAX_AGE_S


def test_with_two_trackers_of_the_same_robots_every_agent_follows_the_same_one_and_the_copies_agree(fleet):
    published: dict[tuple[float, int], str] = {}     # (t, seq) -> the source that published that frame
    arrived: dict[tuple[float, int], int] = {}       # (t, seq) -> its place in the order frames reached this test
    cam2_seen: list[float] = []                      # t of cam2's frames, in the order they reached this test
    lock = threading.Lock()

    def on_frame(sample):
        try:
            msg = decode_frame(sample.payload.to_bytes())
        except WireError:
            return
        with lock:
            published[(msg.t, msg.seq)] = msg.src
            arrived[(msg.t, msg.seq)] = len(cam2_seen)   # how many cam2 frames had arrived before this one
            if msg.src == "cam2":
                cam2_seen.append(msg.t)

    def cam2_silent_before(key: tuple[float, int]) -> bool:
        """No cam2 frame of t at least MAX_AGE_S before this one's (newer ones too: they shadow it as well,
        vsfleet.frames.FrameMerger.offer) had reached the router's subscribers when this one did."""
        return all(t < key[0] - MAX_AGE_S for t in cam2_seen[:arrived[key]])

    frames_sub = fleet.router.declare_subscriber(f"{fleet.keys.prefix}/frame/*", on_frame)
    start_fleet(fleet)
    fleet.start("tracker-cam2", "tracker", "sim", "--fleet", fleet.scenario.fleet, "--src", "cam2", "--rate", "30",
                "--noise-xy", "0.004", "--noise-th", "0.01", "--latency", "0.02", "--seed", "7")
    fleet.wait_alive("tracker", ("sim", "cam2"))
    t_up = time.time()
    fleet.observed.wait_for(lambda o: sum(1 for t, _, _ in o.state if t > t_up + 1.0) >= 3 * 150, timeout_s=30)
    states = list(fleet.observed.state)
    newest = max(m.t for _, _, m in states)
    with lock:   # from half a second after cam2's first frame: before it, sim's frames are the only ones
        t_both = min(t for (t, _), src in published.items() if src == "cam2") + 0.5
    runs: dict[tuple[float, int], dict[str, object]] = {}
    for _, agent, m in states:   # by the frame's own time (the same for every agent), not by arrival; the
        if t_both < m.t < newest - 0.5:   # newest half second's states may still be on their way
            runs.setdefault((m.t, m.seq), {})[agent] = m
    by_all = [group for group in runs.values() if len(group) == 3]
    identical = [g for g in by_all if len({(m.x, m.y, m.th, m.gx, m.gy, m.gth) for m in g.values()}) == 1]
    ts = sorted(t for t, _ in runs)
    print(f"frames run after both trackers were up: {len(runs)} over {ts[-1] - ts[0]:.2f} s of tracker time; "
          f"by every agent: {len(by_all)}; identical: {len(identical)}")
    with lock:
        sources = {published.get(key, "?") for key in runs}
        taken_over = [key for key in runs if published.get(key) != "cam2"]
        unexplained = [key for key in taken_over if key not in arrived or not cam2_silent_before(key)]
    frames_sub.undeclare()
    print(f"sources of the frames run: {sorted(sources)}; not cam2's: {len(taken_over)}, "
          f"of which unexplained (cam2 heard from {MAX_AGE_S} s before them on, or never heard here): "
          f"{len(unexplained)}")
    # one tracker's (first in sort order), for every agent; the other's only where cam2 fell silent for max_age_s
    # (docs/protocol.md, "Frames": the documented failover, seen when a loaded host stalls cam2's process)
    assert "cam2" in sources and sources <= {"cam2", "sim"}
    assert not unexplained, unexplained[:5]
    assert len(by_all) >= 0.99 * len(runs)          # ... every agent ran them ...
    assert len(identical) == len(by_all)            # ... and computed the same bits on each
    fleet.observed.wait_for(at_goal(fleet), timeout_s=40)
    for robot in ("r1", "r2", "r3"):                # and each agent says which tracker it follows
        log = (fleet.log_dir / f"agent-{robot}.log").read_text()
        assert "following tracker source(s) ['cam2']" in log, log[-2000:]
