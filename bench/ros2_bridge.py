"""The ROS 2 bridge's delays, on loopback: command put -> Twist received, and ttl -> zero Twist.

A `vsfleet router` child, `vsfleet bridge ros2` as a child, and a zenoh-ros2-sdk subscriber in
this process (an independent rmw_zenoh implementation). Prints p50/p99/max in ms.
`python -m bench.ros2_bridge [--commands 300] [--expiries 20]`
"""

from __future__ import annotations

import argparse
import os
import queue
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np

from vsfleet.fleetctl import rmw_zenoh as rz
from vsfleet.fleetctl.mission_cmd import stamp
from vsfleet.fleetctl.router import free_loopback_port, wait_listening
from vsfleet.zglue.scenario_file import load_scenario
from tests.integration.conftest import open_client
from vsfleet.wire import CmdMsg, Keys, encode, encode_mission

ROOT = Path(__file__).resolve().parents[1]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--commands", type=int, default=300)
    ap.add_argument("--expiries", type=int, default=20)
    ap.add_argument("--rate", type=float, default=30.0)
    ap.add_argument("--ttl", type=float, default=0.3)
    args = ap.parse_args(argv)
    port = free_loopback_port()
    ep = f"tcp/127.0.0.1:{port}"
    cli = [sys.executable, "-m", "vsfleet.fleetctl.cli"]
    procs = [subprocess.Popen([*cli, "router", "--listen", ep, "--no-multicast-scouting"],
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)]
    wait_listening(port, 20.0)
    procs.append(subprocess.Popen([*cli, "bridge", "ros2", "--robot", "r1", "--fleet", "e2e", "--mode", "client",
                                   "--connect", ep, "--no-multicast-scouting"],
                                  stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
    os.environ["ZENOH_CONFIG_OVERRIDE"] = f'mode="client";scouting/multicast/enabled=false;connect/endpoints=["{ep}"]'
    import zenoh_ros2_sdk as zr
    zr.get_registry(str(ROOT / "tests" / "data" / "ros2_msgs"))
    got: queue.Queue = queue.Queue()
    sub = zr.ROS2Subscriber("/cmd_vel", rz.TWIST, lambda m: got.put((time.perf_counter(), m)), router_port=port,
                            type_hash=rz.type_hash(rz.TWIST, "jazzy"))
    session = open_client(ep)
    keys = Keys("e2e")
    mission = stamp(load_scenario(ROOT / "tests" / "data" / "e2e-triangle.toml").mission, time.time(), 0.0, version=1)
    tick = threading.Event()
    try:
        t_cmd = time.time()
        seq = 0

        def put(vl: float, vr: float) -> float:
            nonlocal seq, t_cmd
            seq += 1
            t_cmd += 1e-3
            at = time.perf_counter()
            session.put(keys.cmd("r1"), encode(CmdMsg(t=t_cmd, seq=seq, vl=vl, vr=vr, ttl=args.ttl)))
            return at

        while True:  # until the bridge has the mission and moves
            session.put(keys.mission, encode_mission(mission))
            put(0.1, 0.1)
            try:
                if got.get(timeout=0.5)[1].linear.x != 0.0:
                    break
            except queue.Empty:
                pass
        tick.wait(args.ttl * 2)
        while not got.empty():
            got.get_nowait()
        lat = []
        for i in range(args.commands):
            v = 0.05 + 0.1 * (i % 2)
            at = put(v, v)
            while True:
                rx, m = got.get(timeout=5.0)
                if abs(m.linear.x - v) < 1e-12:
                    break
            lat.append(rx - at)
            tick.wait(max(0.0, at + 1.0 / args.rate - time.perf_counter()))
        late = []
        for _ in range(args.expiries):
            at = put(0.1, 0.1)
            while True:
                rx, m = got.get(timeout=5.0)
                if m.linear.x == 0.0:
                    break
            late.append(rx - at - args.ttl)
            tick.wait(0.05)
        for name, xs in (("command -> Twist", lat), ("zero Twist after ttl", late)):
            xs = np.array(xs) * 1e3
            print(f"{name}: n={len(xs)} p50 {np.percentile(xs, 50):.2f} ms, p99 {np.percentile(xs, 99):.2f} ms, "
                  f"max {xs.max():.2f} ms")
    finally:
        sub.close()
        session.close()
        for p in reversed(procs):
            p.terminate()
            p.wait(timeout=10)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
