"""The trivial agent: the floor a `vsfleet agent` is measured against in bench/loop.py.

One zenoh client per robot that does what any agent must and nothing more: it decodes
each frame (vsfleet.wire.decode_frame, the same validation) and answers it with a
command and a state message for its robot, on the same keys with the same QoS as
`vsfleet agent`, and declares the same liveliness token. No fit, no control: the
difference between the two fleets at the same N through the same router is the cost
of the agent's own work (the step, its threads and hand-offs).
"""

from __future__ import annotations

import argparse
import signal
import threading

import zenoh

from vsfleet.zglue.zconf import COMMAND_QOS, TELEMETRY_QOS, add_zenoh_args, zenoh_config
from vsfleet.wire import CmdMsg, Keys, StateMsg, WireError, decode_frame, encode


def answer_qos(express: bool | None) -> tuple[dict, dict]:
    """(command QoS, state QoS): the agent's own (None), or the same with express forced on or off."""
    if express is None:
        return COMMAND_QOS, TELEMETRY_QOS
    return dict(COMMAND_QOS, express=express), dict(TELEMETRY_QOS, express=express)


def run(conf: zenoh.Config, robot: str, fleet: str, stop: threading.Event, express: bool | None = None) -> int:
    """Answer every frame until ``stop``; returns the number of frames answered."""
    keys = Keys(fleet)
    answered = [0]
    cmd_qos, state_qos = answer_qos(express)
    with zenoh.open(conf) as session:
        cmd_pub = session.declare_publisher(keys.cmd(robot), **cmd_qos)
        state_pub = session.declare_publisher(keys.state(robot), **state_qos)

        def on_frame(sample: zenoh.Sample) -> None:
            try:
                f = decode_frame(sample.payload.to_bytes())
            except WireError:
                return
            pose = f.poses.get(robot)
            if pose is None:
                return
            cmd_pub.put(encode(CmdMsg(t=f.t, seq=f.seq, vl=0.0, vr=0.0, ttl=0.3)))
            state_pub.put(encode(StateMsg(t=f.t, seq=f.seq, x=0.0, y=0.0, th=0.0, gx=0.0, gy=0.0, gth=0.0,
                                          cost=0.0, err=0.0, used=tuple(sorted(f.poses)), rejected=0)))
            answered[0] += 1

        sub = session.declare_subscriber(keys.frame(), on_frame)
        token = session.liveliness().declare_token(keys.alive("agent", robot))
        stop.wait()
        token.undeclare()
        sub.undeclare()
    return answered[0]


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m bench.trivial_agent", description=__doc__.splitlines()[0])
    p.add_argument("--robot", required=True)
    p.add_argument("--fleet", default="bench")
    p.add_argument("--express", choices=("agent", "on", "off"), default="agent",
                   help="the commands' and states' express flag: as vsfleet agent's (default), or forced")
    add_zenoh_args(p)
    args = p.parse_args(argv)
    stop = threading.Event()
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, lambda *_: stop.set())
    run(zenoh_config(args), args.robot, args.fleet, stop,
        express={"agent": None, "on": True, "off": False}[args.express])
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
