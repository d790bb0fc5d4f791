"""vsfleet replay FILE.mcap: publish a recording's messages back into a key space.

Publishes the ``raw`` channels written by ``vsfleet record`` (and by ``vsfleet
run``) on their keys, in recorded order, at the recorded pace (``--speed X``:
X times faster). Every sample carries its recorded publish time as its zenoh
timestamp, so a recorder downstream records the same publish times. Liveliness
tokens are declared and undeclared as recorded. ``--fleet NAME`` moves the
messages to ``vs/NAME/...``. The latest replayed mission answers mission
queries, as an agent would. All samples go reliably (congestion control
block) at one priority, so their order is kept.

A recording made before trackers published frames (``vs/<fleet>/frame/<src>``,
which agents subscribe to) has only ``pose/<robot>``: replay then also
publishes one frame per tracker frame, the recorded poses grouped by
``(src, seq)``, right after the group's last pose, with ``t`` the newest pose
time of the group (``--no-frames`` turns this off). Sources whose frames are
in the recording are replayed as recorded.
"""

from __future__ import annotations

import argparse
import logging
import math
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Sequence

import zenoh
from mcap.exceptions import McapError

from vsfleet.wire import FrameMsg, WireError, check_name, decode_pose, encode_frame

from vsfleet.zglue.lifecycle import StopFlag
from vsfleet.zglue.program import Refused, common_flags, program
from .record import LIVELINESS, RAW, LogRecord, read_log, seconds_to_ns, split_key
from vsfleet.zglue.zconf import SessionError, open_session, zenoh_config

log = logging.getLogger("vsfleet.replay")

REPLAY_QOS = dict(congestion_control=zenoh.CongestionControl.BLOCK, priority=zenoh.Priority.DATA)


def remap_key(key: str, fleet: str | None) -> str:
    """``vs/<any>/rest`` -> ``vs/<fleet>/rest`` (other keys, and fleet None, unchanged)."""
    if fleet is None:
        return key
    parts = split_key(key)
    if parts is None:
        return key
    return f"vs/{fleet}/{key.split('/', 2)[2]}"


def offsets_s(records: Sequence[LogRecord], speed: float) -> list[float]:
    """When to send each record [s after the start]: its log time since the first, divided by speed."""
    if speed <= 0 or not math.isfinite(speed):
        raise ValueError(f"speed must be a finite number > 0, got {speed}")
    if not records:
        return []
    t0 = records[0].log_time_ns
    return [(r.log_time_ns - t0) * 1e-9 / speed for r in records]


def with_frames(records: Sequence[LogRecord]) -> list[LogRecord]:
    """``records`` plus one ``vs/<fleet>/frame/<src>`` record per recorded (src, seq) of pose/<robot>.

    A frame goes right after the last pose of its group (a group ends when that
    source's next seq starts, or at the end), with that pose's log time; its t is
    the newest pose time in the group. Sources that have frame records, and poses
    that do not decode, are left as they are.
    """
    recorded = set()
    for r in records:
        parts = split_key(r.key) if r.role == RAW else None
        if parts is not None and parts[1] == "frame" and parts[2]:
            recorded.add((parts[0], parts[2]))
    after: dict[int, list[LogRecord]] = {}
    open_groups: dict[tuple[str, str], tuple[int, int, float, dict]] = {}  # (fleet, src) -> (seq, last i, t, poses)

    def close(fleet: str, src: str) -> None:
        seq, last, t, poses = open_groups.pop((fleet, src))
        payload = encode_frame(FrameMsg(t=t, seq=seq, src=src, poses=poses))
        after.setdefault(last, []).append(LogRecord(records[last].log_time_ns, seconds_to_ns(t),
                                                    f"vs/{fleet}/frame/{src}", payload, RAW))

    for i, r in enumerate(records):
        parts = split_key(r.key) if r.role == RAW else None
        if parts is None or parts[1] != "pose" or not parts[2]:
            continue
        fleet, _, robot = parts
        try:
            m = decode_pose(r.payload)
            check_name(robot, "robot")
            src = check_name(m.src, "src")
        except WireError:
            continue
        if (fleet, src) in recorded:
            continue
        group = open_groups.get((fleet, src))
        if group is not None and group[0] != m.seq:
            close(fleet, src)
            group = None
        seq, _, t, poses = group or (m.seq, i, m.t, {})
        poses[robot] = (m.x, m.y, m.th)
        open_groups[(fleet, src)] = (seq, i, max(t, m.t), poses)
    for fleet, src in list(open_groups):
        close(fleet, src)
    out: list[LogRecord] = []
    for i, r in enumerate(records):
        out.append(r)
        out.extend(after.get(i, ()))
    return out


def ns_timestamp(t_ns: int, ident: zenoh.TimestampId) -> zenoh.Timestamp:
    return zenoh.Timestamp(zenoh.NTP64(t_ns // 1_000_000_000, t_ns % 1_000_000_000), ident)


@dataclass(frozen=True)
class ReplayStats:
    sent: int
    tokens: int
    log_span_s: float
    elapsed_s: float
    interrupted: bool


class Progress:
    """Progress with an ETA: a rich bar on a terminal, else a line every ``every_s`` seconds."""

    def __init__(self, total_s: float, n: int, speed: float, enabled: bool, every_s: float = 1.0,
                 out=None) -> None:
        self.total_s, self.n, self.speed, self.every_s = total_s, n, speed, every_s
        self.out = out or sys.stderr
        self.enabled = enabled
        self._next = 0.0
        self._bar = None
        if enabled and self.out.isatty():
            from rich.console import Console
            from rich.progress import BarColumn, Progress as RichProgress, TextColumn, TimeRemainingColumn
            self._bar = RichProgress(TextColumn("replay"), BarColumn(), TextColumn("{task.fields[sent]}"),
                                     TextColumn("ETA"), TimeRemainingColumn(), console=Console(file=self.out))
            self._task = self._bar.add_task("replay", total=max(total_s, 1e-9), sent=f"0/{n}")
            self._bar.start()

    @staticmethod
    def line(done_s: float, total_s: float, sent: int, n: int, speed: float) -> str:
        eta = max(0.0, total_s - done_s) / speed
        return (f"[replay] {done_s:7.1f}/{total_s:.1f} s of log, {sent}/{n} messages, "
                f"x{speed:g}, ETA {eta:5.1f} s")

    def update(self, done_s: float, sent: int, now_s: float) -> None:
        if not self.enabled:
            return
        if self._bar is not None:
            self._bar.update(self._task, completed=done_s, sent=f"{sent}/{self.n}")
        elif now_s >= self._next:
            self._next = now_s + self.every_s
            print(self.line(done_s, self.total_s, sent, self.n, self.speed), file=self.out, flush=True)

    def close(self, done_s: float, sent: int) -> None:
        if self._bar is not None:
            self._bar.update(self._task, completed=done_s, sent=f"{sent}/{self.n}")
            self._bar.stop()
        elif self.enabled:
            print(self.line(done_s, self.total_s, sent, self.n, self.speed), file=self.out, flush=True)


class MissionAnswers:
    """Answers queries on mission keys with the latest replayed mission."""

    def __init__(self) -> None:
        self.latest: dict[str, bytes] = {}
        self.lock = threading.Lock()

    def on_query(self, key: str, query: zenoh.Query) -> None:
        with self.lock:
            payload = self.latest.get(key)
        if payload is not None:
            query.reply(key, payload)


def replay_records(session: zenoh.Session, records: Sequence[LogRecord], speed: float = 1.0,
                   fleet: str | None = None, stop: StopFlag | None = None, progress: bool = True,
                   wait_subscribers_s: float = 1.0, clock: Callable[[], float] = time.monotonic,
                   out=None, frames: bool = True) -> ReplayStats:
    """Publish ``records`` (raw and liveliness) on ``session`` in order; see the module doc.

    frames: also publish the frames of sources recorded as pose/<robot> only (with_frames).
    """
    stop = stop or StopFlag(install_signals=False)
    if fleet is not None:
        check_name(fleet, "fleet")
    records = [r for r in records if r.role in (RAW, LIVELINESS)]
    if frames:
        records = with_frames(records)
    when = offsets_s(records, speed)
    ident = session.new_timestamp().get_id()
    raw_keys = sorted({remap_key(r.key, fleet) for r in records if r.role == RAW})
    pubs = {k: session.declare_publisher(k, **REPLAY_QOS) for k in raw_keys}
    answers = MissionAnswers()
    queryables = [session.declare_queryable(k, lambda q, k=k: answers.on_query(k, q))
                  for k in raw_keys if (split_key(k) or ("", "", ""))[1:] == ("mission", None)]
    tokens: dict[str, zenoh.LivelinessToken] = {}
    n_tokens = 0
    if pubs and wait_subscribers_s > 0:
        deadline = clock() + wait_subscribers_s
        while not all(p.matching_status.matching for p in pubs.values()) and clock() < deadline:
            if stop.wait(0.01):
                break
    span_s = (records[-1].log_time_ns - records[0].log_time_ns) * 1e-9 if records else 0.0
    bar = Progress(span_s, len(records), speed, progress, out=out)
    sent = 0
    t_start = clock()
    try:
        for rec, at in zip(records, when):
            remaining = t_start + at - clock()
            if remaining > 0 and stop.wait(remaining):
                break
            if stop.is_set():
                break
            key = remap_key(rec.key, fleet)
            if rec.role == RAW:
                pubs[key].put(rec.payload, timestamp=ns_timestamp(rec.publish_time_ns, ident))
                split = split_key(key)
                if split is not None and split[1:] == ("mission", None):
                    with answers.lock:
                        answers.latest[key] = rec.payload
            elif rec.alive:
                if key not in tokens:
                    tokens[key] = session.liveliness().declare_token(key)
                    n_tokens += 1
            elif key in tokens:
                tokens.pop(key).undeclare()
            sent += 1
            bar.update(at * speed, sent, clock())
    finally:
        bar.close(((records[sent - 1].log_time_ns - records[0].log_time_ns) * 1e-9) if sent else 0.0, sent)
        for t in tokens.values():
            t.undeclare()
        for q in queryables:
            q.undeclare()
        for p in pubs.values():
            p.undeclare()
    return ReplayStats(sent=sent, tokens=n_tokens, log_span_s=span_s, elapsed_s=clock() - t_start,
                       interrupted=stop.is_set())


def replay(conf: zenoh.Config, path: str | Path, speed: float = 1.0, fleet: str | None = None,
           stop: StopFlag | None = None, progress: bool = True, wait_subscribers_s: float = 1.0,
           frames: bool = True) -> ReplayStats:
    records = read_log(path)
    with open_session(conf) as session:
        return replay_records(session, records, speed, fleet, stop, progress, wait_subscribers_s, frames=frames)


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="vsfleet replay", description=__doc__.splitlines()[0])
    p.add_argument("file", help="MCAP file written by vsfleet record or vsfleet run")
    p.add_argument("--speed", type=float, default=1.0, help="replay X times faster than recorded (default 1)")
    p.add_argument("--fleet", default=None, help="publish under vs/<fleet>/ instead of the recorded fleet")
    p.add_argument("--wait-subscribers", type=float, default=1.0, metavar="S",
                   help="wait up to S seconds for a subscriber on every key before starting (default 1)")
    p.add_argument("--no-frames", action="store_true",
                   help="do not publish frame/<src> for recordings that have only pose/<robot>")
    p.add_argument("--no-progress", action="store_true")
    return common_flags(p)


@program(build_parser, log)
def main(args: argparse.Namespace) -> int:
    stop = StopFlag()
    try:
        if args.speed <= 0 or not math.isfinite(args.speed):
            raise ValueError(f"--speed must be > 0, got {args.speed}")
        if args.fleet is not None:
            check_name(args.fleet, "fleet")
        stats = replay(zenoh_config(args), args.file, args.speed, args.fleet, stop,
                       progress=not args.no_progress, wait_subscribers_s=args.wait_subscribers,
                       frames=not args.no_frames)
    except SessionError:  # one line from `vsfleet`, like every program's
        raise
    except (OSError, ValueError, McapError, zenoh.ZError) as exc:
        raise Refused(str(exc)) from exc
    log.info("replayed %d messages (%.1f s of log) in %.1f s%s", stats.sent, stats.log_span_s,
             stats.elapsed_s, ", interrupted" if stats.interrupted else "")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
