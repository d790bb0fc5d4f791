"""vsfleet tracker sim: the paper's VGPS, simulated. Reads truth, publishes noisy frames.

Each frame (30 Hz by default) samples the latest truth of every robot, adds
Gaussian position and heading noise (drawn for all robots at once), and after
``latency_s`` publishes one message with every robot's pose on
``vs/<fleet>/frame/<src>``, and each pose on ``pose/<robot>`` for key-expression
tools (``--no-poses`` leaves those out); a whole frame is dropped with
probability ``drop_prob``. ``t`` is the observation time (the truth sample's time).
"""

from __future__ import annotations

import argparse
import logging
import threading
from collections import deque
from typing import Callable

import numpy as np
import zenoh

from vsfleet.zglue.lifecycle import Rejections, StopFlag, pace, wall_clock
from vsfleet.zglue.program import Refused, common_flags, program, refusing
from vsfleet.zglue.zconf import BURST_QOS, STREAM_QOS, open_session, zenoh_config
from vsfleet.kinematics import wrap_angles
from vsfleet.scenario import TrackerParams
from vsfleet.wire import FrameMsg, Keys, PoseMsg, TruthMsg, decode_truth, encode, encode_frame

log = logging.getLogger("vsfleet.tracker")

TRUTH_MAX_AGE_S = 0.1


class SimTracker:
    """Frames from the latest truth; pure apart from its seeded RNG."""

    def __init__(self, params: TrackerParams, src: str = "sim", seed: int = 0,
                 clock_offset_s: float = 0.0) -> None:
        self.params = params
        self.src = src
        self.clock_offset_s = clock_offset_s  # added to every published t: a skewed tracker host
        self.rng = np.random.default_rng(seed)
        self.truth: dict[str, TruthMsg] = {}
        self.lock = threading.Lock()
        self.seq = 0
        self.dropped = 0
        self.rejections = Rejections(log)

    def on_truth(self, keys: Keys, key: str, payload: bytes) -> None:
        try:
            robot = keys.robot_of(key, "truth")
            msg = decode_truth(payload)
        except Exception as exc:  # noqa: BLE001 - WireError, or anything else: counted, never fatal
            self.rejections.reject(key, str(exc))
            return
        with self.lock:
            held = self.truth.get(robot)
            if held is None or msg.t > held.t:
                self.truth[robot] = msg

    def frame(self, now: float) -> FrameMsg | None:
        """Observe every robot with fresh truth; None when the frame is dropped or nothing is fresh."""
        self.seq += 1
        with self.lock:
            truth = {r: m for r, m in self.truth.items() if now - m.t <= TRUTH_MAX_AGE_S}
        if not truth or self.rng.random() < self.params.drop_prob:
            self.dropped += bool(truth)
            return None
        robots = sorted(truth)
        xyth = np.array([[truth[r].x, truth[r].y, truth[r].th] for r in robots])
        noise = np.zeros_like(xyth)
        if self.params.noise_xy_m > 0:
            noise[:, :2] = self.rng.normal(0.0, self.params.noise_xy_m, (len(robots), 2))
        if self.params.noise_th_rad > 0:
            noise[:, 2] = self.rng.normal(0.0, self.params.noise_th_rad, len(robots))
        xyth += noise
        xyth[:, 2] = wrap_angles(xyth[:, 2])
        # the observation time: the newest truth sample's (all robots are sampled together)
        t = max(truth[r].t for r in robots) + self.clock_offset_s
        return FrameMsg(t=t, seq=self.seq, src=self.src,
                        poses={r: (float(p[0]), float(p[1]), float(p[2])) for r, p in zip(robots, xyth)})


def run_tracker(conf: zenoh.Config, params: TrackerParams, fleet: str = "demo", src: str = "sim",
                seed: int = 0, stop: StopFlag | None = None,
                clock: Callable[[], float] = wall_clock, clock_offset_s: float = 0.0,
                poses: bool = True) -> SimTracker:
    stop = stop or StopFlag()
    keys = Keys(fleet)
    tracker = SimTracker(params, src, seed, clock_offset_s)
    period = 1.0 / params.rate_hz
    pending: deque[tuple[float, FrameMsg | None]] = deque()
    with open_session(conf) as session:
        pubs: dict[str, zenoh.Publisher] = {}
        frame_pub = session.declare_publisher(keys.frame(src), **STREAM_QOS)
        token = session.liveliness().declare_token(keys.alive("tracker", src))
        sub = session.declare_subscriber(keys.truth(), lambda s: tracker.on_truth(
            keys, str(s.key_expr), s.payload.to_bytes()))
        log.info("tracker %s up at %.1f Hz", src, params.rate_hz)
        next_frame = clock()
        try:
            while not stop.is_set():
                now = clock()
                if now >= next_frame:
                    pending.append((now + params.latency_s, tracker.frame(now)))
                    next_frame += period
                    if next_frame < now:  # fell behind: skip frames rather than burst
                        next_frame = now + period
                while pending and pending[0][0] <= clock():
                    msg = pending.popleft()[1]
                    if msg is None:
                        continue
                    frame_pub.put(encode_frame(msg))
                    for robot, (x, y, th) in msg.poses.items() if poses else ():
                        if robot not in pubs:
                            pubs[robot] = session.declare_publisher(keys.pose(robot), **BURST_QOS)
                        pubs[robot].put(encode(PoseMsg(t=msg.t, seq=msg.seq, x=x, y=y, th=th, src=msg.src)))
                pace(min(next_frame, pending[0][0]) if pending else next_frame, stop, clock)
        finally:
            log.info("tracker stopping after %d frames (%d dropped), %d rejected",
                     tracker.seq, tracker.dropped, tracker.rejections.count)
            sub.undeclare()
            token.undeclare()
    return tracker


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="vsfleet tracker sim", description=__doc__.splitlines()[0])
    p.add_argument("--fleet", default="demo")
    p.add_argument("--src", default="sim", help="tracker id, sent as 'src'")
    p.add_argument("--rate", type=float, default=30.0, help="frame rate [Hz]")
    p.add_argument("--noise-xy", type=float, default=0.001, help="position noise sigma [m]")
    p.add_argument("--noise-th", type=float, default=0.005, help="heading noise sigma [rad]")
    p.add_argument("--latency", type=float, default=0.005, help="publish latency [s]")
    p.add_argument("--drop", type=float, default=0.0, help="frame drop probability")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--clock-offset", type=float, default=0.0,
                   help="add this to every published t [s]: simulates a tracker host with a skewed clock")
    p.add_argument("--no-poses", action="store_true",
                   help="publish frames only, not also pose/<robot> for key-expression tools")
    return common_flags(p)


@program(build_parser, log)
def main(args: argparse.Namespace) -> int:
    with refusing(ValueError):
        params = TrackerParams(rate_hz=args.rate, noise_xy_m=args.noise_xy, noise_th_rad=args.noise_th,
                               latency_s=args.latency, drop_prob=args.drop)
        Keys(args.fleet)
        if not (args.rate > 0 and 0 <= args.drop <= 1 and min(args.noise_xy, args.noise_th, args.latency) >= 0):
            raise ValueError("rate must be > 0, drop in [0, 1], noise and latency >= 0")
    if abs(args.clock_offset) > 3600:
        raise Refused("--clock-offset must be within an hour")
    run_tracker(zenoh_config(args), params, args.fleet, args.src, args.seed,
                clock_offset_s=args.clock_offset, poses=not args.no_poses)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
