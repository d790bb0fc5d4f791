"""Decoding one tracker frame: the core's decoder (vsfleet._core.decode_frame) against the reference
(vsfleet.wire.decode_frame), and msgpack.unpackb alone (no checks) as the floor of the Python way.

For n robots (3, 30, 100 by default), `--frames` distinct frames as the tracker encodes them
(encode_frame of noisy poses) are decoded in a batch, `--repeats` times; the time per frame is the
batch's CPU time (this thread's) over its frames, and its median and best over the repeats are
reported [us]. Both decoders are checked to agree on every frame first. One process, no zenoh.

Run: .venv/bin/python -m bench.decode [--robots 3 30 100] [--docs | --out DIR]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import random
import statistics
import time
from pathlib import Path

import msgpack

from vsfleet import _core
from vsfleet.wire import FrameMsg, decode_frame, encode_frame

from .outputs import DOCS, add_output_flags


def tracker_payloads(n: int, count: int, seed: int = 0) -> list[bytes]:
    """count frames of n robots on a circle, 1 mm noise, at 30 Hz, as the tracker encodes them."""
    rng = random.Random(seed)
    out = []
    for k in range(count):
        poses = {f"r{i:03d}": (1.5 * (i % 10) + rng.gauss(0, 1e-3), 0.4 * (i // 10) + rng.gauss(0, 1e-3),
                               rng.uniform(-3.14, 3.14)) for i in range(n)}
        out.append(encode_frame(FrameMsg(t=10.0 + k / 30.0, seq=k + 1, src="sim", poses=poses)))
    return out


def check_agreement(payloads: list[bytes]) -> None:
    for p in payloads:
        ref = decode_frame(p)
        t, seq, src, ids, xyth = _core.decode_frame(p)
        flat = memoryview(xyth).cast("d").tolist()
        if (t, seq, src, ids, flat) != (ref.t, ref.seq, ref.src, tuple(ref.poses),
                                        [v for pose in ref.poses.values() for v in pose]):
            raise SystemExit(f"the decoders disagree on a frame of {len(ids)} robots")


def time_per_frame_us(decode, payloads: list[bytes], repeats: int) -> tuple[float, float]:
    """(median, best) over repeats of one batch's CPU time per frame [us]."""
    per = []
    for _ in range(repeats):
        t0 = time.thread_time_ns()
        for p in payloads:
            decode(p)
        per.append((time.thread_time_ns() - t0) / 1e3 / len(payloads))
    return statistics.median(per), min(per)


def unpack_only(p: bytes):
    return msgpack.unpackb(p, raw=False)


def measure(sizes: list[int], frames: int, repeats: int) -> dict:
    rows = []
    for n in sizes:
        payloads = tracker_payloads(n, frames, seed=n)
        check_agreement(payloads)
        row = {"n": n, "bytes": len(payloads[0])}
        for name, fn in (("core", _core.decode_frame), ("reference", decode_frame), ("unpackb", unpack_only)):
            fn(payloads[0])  # warm
            row[f"{name}_p50_us"], row[f"{name}_best_us"] = time_per_frame_us(fn, payloads, repeats)
        row["speedup"] = row["reference_p50_us"] / row["core_p50_us"]
        rows.append(row)
    load = " ".join(f"{x:.2f}" for x in os.getloadavg())
    return {"machine": f"{platform.machine()}, {os.cpu_count()} cores, python {platform.python_version()}, "
                       f"load average {load} (a shared machine)",
            "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()), "frames": frames, "repeats": repeats,
            "rows": rows}


def report(res: dict) -> str:
    lines = ["## Decoding a frame: the core against the reference", "",
             f"`bench/decode.py` ({res['machine']}, {res['date']}; {res['frames']} frames per batch, median and best "
             f"of {res['repeats']} batches, CPU time of the decoding thread). `core`: `vsfleet._core.decode_frame` "
             "(docs/decoder.md), which returns (t, seq, src, ids, poses as float64 bytes); `reference`: "
             "`vsfleet.wire.decode_frame`, which returns a `FrameMsg`; `unpackb`: `msgpack.unpackb` alone, no checks. "
             "Both decoders agree on every frame measured.", "",
             "| robots | bytes | core [us] | reference [us] | unpackb only [us] | reference / core |",
             "| ---: | ---: | ---: | ---: | ---: | ---: |"]
    for r in res["rows"]:
        lines.append(f"| {r['n']} | {r['bytes']} | {r['core_p50_us']:.2f} (best {r['core_best_us']:.2f}) | "
                     f"{r['reference_p50_us']:.1f} (best {r['reference_best_us']:.1f}) | "
                     f"{r['unpackb_p50_us']:.1f} | {r['speedup']:.1f}x |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--robots", type=int, nargs="+", default=[3, 30, 100])
    ap.add_argument("--frames", type=int, default=300, help="distinct frames per batch")
    ap.add_argument("--repeats", type=int, default=15, help="batches per decoder and size")
    add_output_flags(ap, "decode", DOCS / "bench" / "sections", "decode.md and decode.json")
    args = ap.parse_args(argv)
    res = measure(args.robots, args.frames, args.repeats)
    text = report(res)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "decode.md").write_text(text)
    (out / "decode.json").write_text(json.dumps(res, indent=1) + "\n")
    print(text, end="")
    print(f"written: {out / 'decode.md'}, {out / 'decode.json'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
