"""vsfleet foxglove: a live Foxglove WebSocket server on a fleet's key space (vs/<fleet>/**).

Open Foxglove, "Open connection", Foxglove WebSocket, ``ws://HOST:PORT``
(default ws://127.0.0.1:8765), and load docs/foxglove-layout.json (or one
written with ``--write-layout``). Topics (the same that ``vsfleet record``
writes, see fleetctl.foxglove_views and docs/foxglove.md): ``/foxglove/...``
drawables with the foxglove-sdk's schemas (PoseInFrame, SceneUpdate, Log), and
``/json/<key>`` every message as JSON (jsonschema ``vsfleet.<kind>``) to plot:
``/json/vs/<fleet>/state/<robot>.err`` (the robot's deviation [m]),
``.cost`` (the fit's cost [m]), ``/json/vs/<fleet>/cmd/<robot>.vl`` / ``.vr``
(wheel commands [m/s]); ``/json/vs/<fleet>/mission`` is the mission. The
server broadcasts the tracker's clock (the newest frame or pose time) as its
time. At start it asks the fleet for its mission (as ``vsfleet record`` does).
"""

from __future__ import annotations

import argparse
import json
import logging
import queue
import threading
import time
from pathlib import Path
from typing import Any

import foxglove
import zenoh
from foxglove.websocket import Capability

from vsfleet.wire import Keys, WireError, check_name

from .foxglove_views import FleetViews, View
from vsfleet.zglue.lifecycle import StopFlag
from vsfleet.zglue.peers import current_missions
from vsfleet.zglue.program import Refused, common_flags, program, refusing
from .record import json_mirror, payload_time_ns
from vsfleet.zglue.zconf import open_session, zenoh_config

log = logging.getLogger("vsfleet.foxglove")

QUEUE_DEPTH = 20_000  # messages waiting for the view thread; beyond, the newest are dropped (counted)


class ChannelSink:
    """Foxglove channels of one Context, made on first use: typed for SDK messages, JSON otherwise."""

    def __init__(self, context: foxglove.Context) -> None:
        self.context = context
        self.channels: dict[str, Any] = {}

    def wanted(self, topic: str) -> bool:
        """False when the channel exists and no client subscribes (so the message need not be built)."""
        ch = self.channels.get(topic)
        return ch is None or ch.has_sinks()

    def log_view(self, view: View) -> None:
        ch = self.channels.get(view.topic)
        if ch is None:
            cls = getattr(foxglove.channels, type(view.message).__name__ + "Channel")
            ch = self.channels[view.topic] = cls(view.topic, context=self.context)
        ch.log(view.message, log_time=view.t_ns)

    def log_json(self, topic: str, schema: dict, obj: Any, t_ns: int) -> None:
        ch = self.channels.get(topic)
        if ch is None:
            ch = self.channels[topic] = foxglove.Channel(topic, schema=schema, message_encoding="json",
                                                         context=self.context)
        ch.log(obj, log_time=t_ns)


class LiveServer:
    """A Foxglove WebSocket server fed by a zenoh subscriber on ``vs/<fleet>/**``.

    Samples are queued by the zenoh callback and turned into views on one thread.
    ``handled`` counts messages processed; ``wait_handled`` waits on it (tests).
    """

    def __init__(self, conf: zenoh.Config, fleet: str = "demo", host: str = "127.0.0.1", port: int = 8765,
                 query_mission: bool = True) -> None:
        self.keys = Keys(check_name(fleet, "fleet"))
        self.context = foxglove.Context()
        self.sink = ChannelSink(self.context)
        self.views = FleetViews(wanted=self.sink.wanted)  # views nobody subscribes to are not built
        self.server = None
        self._queue: queue.Queue = queue.Queue(maxsize=QUEUE_DEPTH)
        self._cond = threading.Condition()
        self.handled = 0
        self.dropped = 0
        self._last_time_ns = 0
        self._thread = threading.Thread(target=self._drain, name="foxglove-views", daemon=True)
        self._thread.start()
        try:  # subscribed before the port listens: a client that can connect sees every message from then on
            self.session = open_session(conf)
            self.sub = self.session.declare_subscriber(self.keys.everything, self._on_sample)
            if query_mission:
                for key, payload in current_missions(self.session, fleet, timeout_s=2.0):
                    self._put(key, payload)
            self.server = foxglove.start_server(name=f"vsfleet {fleet}", host=host, port=port,
                                                capabilities=[Capability.Time], context=self.context)
        except Exception:
            self.close()
            raise

    @property
    def port(self) -> int:
        return self.server.port

    def _on_sample(self, sample: zenoh.Sample) -> None:
        if sample.kind == zenoh.SampleKind.PUT:
            self._put(str(sample.key_expr), sample.payload.to_bytes())

    def _put(self, key: str, payload: bytes) -> None:
        try:
            self._queue.put_nowait((key, payload, time.time_ns()))
        except queue.Full:
            self.dropped += 1
            if self.dropped in (1, 10, 100) or self.dropped % 1000 == 0:
                log.warning("view queue full: %d messages dropped so far", self.dropped)

    def _drain(self) -> None:
        while True:
            item = self._queue.get()
            if item is None:
                return
            try:
                self.handle(*item)
            except Exception:  # one bad message must not stop the view
                log.exception("cannot show a message on %s", item[0])
            with self._cond:
                self.handled += 1
                self._cond.notify_all()

    def handle(self, key: str, payload: bytes, recv_ns: int) -> None:
        """Show one message: its Foxglove views, its JSON mirror, and the tracker's clock."""
        t_ns = self.views.now_ns or recv_ns
        for view in self.views.on_message(key, payload, t_ns):
            self.sink.log_view(view)
        topic = f"/json/{key}"
        if self.sink.wanted(topic):
            mirror = json_mirror(key, payload)
            if mirror is not None:  # stamped with the message's own t, else the tracker's clock
                self.sink.log_json(topic, mirror[2], mirror[3], payload_time_ns(payload) or t_ns)
        if self.views.now_ns > self._last_time_ns and self.server is not None:
            self._last_time_ns = self.views.now_ns
            self.server.broadcast_time(self._last_time_ns)

    def wait_handled(self, n: int, timeout_s: float) -> bool:
        with self._cond:
            return self._cond.wait_for(lambda: self.handled >= n, timeout=timeout_s)

    def close(self) -> None:
        sub = getattr(self, "sub", None)
        if sub is not None:
            sub.undeclare()
        session = getattr(self, "session", None)
        if session is not None:
            session.close()
        if self._thread.is_alive():
            self._queue.put(None)
            self._thread.join(timeout=5.0)
        if self.server is not None:
            self.server.stop()

    def __enter__(self) -> "LiveServer":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


# ---------------------------------------------------------------- layout


def layout(fleet: str, robots: list[str]):
    """A Foxglove layout (foxglove.layouts.Layout) for ``fleet``: 3-D scene, plots per robot, log, mission."""
    import foxglove.layouts as fl

    base, js = f"/foxglove/vs/{fleet}", f"/json/vs/{fleet}"
    topics = {f"{base}/scene": fl.BaseRendererSceneUpdateTopicSettings(visible=True),
              f"{base}/goal": fl.BaseRendererPoseTopicSettings(visible=True)}
    for r in robots:
        topics[f"{base}/truth/{r}"] = fl.BaseRendererPoseTopicSettings(visible=False)
    three = fl.ThreeDeePanel(title="fleet", config=fl.ThreeDeeConfig(follow_tf="world", topics=topics))

    def plot(title: str, series: list[tuple[str, str]]):
        return fl.PlotPanel(title=title, config=fl.PlotConfig(
            paths=[fl.PlotSeries(value=v, label=lbl) for v, lbl in series]))

    deviation = plot("deviation [m]", [(f"{js}/state/{r}.err", r) for r in robots])
    cost = plot("fit cost [m]", [(f"{js}/state/{r}.cost", r) for r in robots])
    wheels = plot("wheel commands [m/s]", [(f"{js}/cmd/{r}.{w}", f"{r} {w}") for r in robots for w in ("vl", "vr")])
    logs = fl.LogPanel(title="events and rejections", config=fl.LogConfig(topic_to_render=f"{base}/log"))
    mission = fl.RawMessagesPanel(title="mission", config=fl.RawMessagesConfig(topic_path=f"{js}/mission"))
    right = fl.SplitContainer(direction="column", items=[fl.SplitItem(content=p) for p in (deviation, cost, wheels)])
    left = fl.SplitContainer(direction="column", items=[
        fl.SplitItem(content=three, proportion=3), fl.SplitItem(content=logs, proportion=1)])
    return fl.Layout(content=fl.SplitContainer(direction="row", items=[
        fl.SplitItem(content=left, proportion=3), fl.SplitItem(content=right, proportion=2),
        fl.SplitItem(content=mission, proportion=1)]))


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="vsfleet foxglove", description=__doc__.splitlines()[0])
    p.add_argument("--fleet", default="demo", help="fleet name: shows vs/<fleet>/** (default demo)")
    p.add_argument("--host", default="127.0.0.1", help="address to serve on (default 127.0.0.1)")
    p.add_argument("--port", type=int, default=8765, help="WebSocket port (default 8765; 0: any free port)")
    p.add_argument("--no-mission-query", action="store_true", help="do not ask the fleet for its mission at start")
    p.add_argument("--write-layout", metavar="FILE", help="write a Foxglove layout for --fleet and --robots, and exit")
    p.add_argument("--robots", default="r1,r2,r3", help="robot ids for --write-layout (comma-separated)")
    return common_flags(p)


@program(build_parser, log)
def main(args: argparse.Namespace) -> int:
    with refusing(WireError):
        check_name(args.fleet, "fleet")
        robots = [check_name(r.strip(), "robot") for r in args.robots.split(",") if r.strip()]
    if args.write_layout:
        text = json.dumps(json.loads(layout(args.fleet, robots).to_json()), indent=2)
        Path(args.write_layout).write_text(text + "\n")
        log.info("layout for fleet %s (%s) written to %s", args.fleet, ", ".join(robots), args.write_layout)
        return 0
    stop = StopFlag()
    try:
        server = LiveServer(zenoh_config(args), args.fleet, args.host, args.port,
                            query_mission=not args.no_mission_query)
    except (OSError, RuntimeError, zenoh.ZError) as exc:
        raise Refused(f"cannot serve: {exc}") from exc
    with server:
        print(f"foxglove: open ws://{args.host}:{server.port} in Foxglove (fleet {args.fleet}), "
              f"or {server.server.app_url()}; layout docs/foxglove-layout.json", flush=True)
        while not stop.wait(1.0):
            pass
        log.info("foxglove server stopping after %d messages (%d dropped, %d turned away)",
                 server.handled, server.dropped, server.views.turned_away)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
