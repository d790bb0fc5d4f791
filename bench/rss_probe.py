"""What grows a `vsfleet router`'s memory (issue 30, RSS): one soak injection at a time, accelerated.

A `vsfleet router` on a free loopback port, a persistent sink session (client: a subscriber on vs/probe/**
and a liveliness subscriber on vs/probe/alive/**, as the soak's observer and the agents) and a persistent
tracker-like publisher (30 Hz, one key; the fleet's steady traffic). Then one injection, repeated every
--every s for --minutes:

- none:  nothing more (the baseline: steady traffic only);
- kill:  a child process opens a client session as an agent does (liveliness token vs/probe/alive/<n>,
         a subscriber, a queryable, a few puts; --decl chooses which) and is SIGKILLed 1 s later (the soak's
         agent kill);
- close: the same child, closing its session cleanly instead (SIGTERM, handled);
- fuzz:  `vsfleet fuzz --fleet probe --duration --fuzz-s` (two new sessions, a subscriber on a new key
         vsfuzz/<zid>/barrier, invalid messages on the fleet's keys; the soak's fuzz segments);
- fuzzlong: one `vsfleet fuzz` for the whole run (the same traffic, no new session).

The router's RssAnon and VmRSS (/proc/<pid>/status) every 2 s, with the count of injections done so far, go to
stdout (JSON lines), then the summary (one line): RssAnon at 30 s, at the middle and at the end, and the growth
per injection over the second half. It writes no file (the children's output is discarded). --env KEY=VALUE is set in the router's environment (e.g. MALLOC_ARENA_MAX=1).

Run: .venv/bin/python -m bench.rss_probe --mode kill --every 3 --minutes 5 > /tmp/probe-kill.jsonl
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

CHILD = r"""
import signal, sys, time, zenoh
n, endpoint, decl = sys.argv[1], sys.argv[2], sys.argv[3].split(",")
conf = zenoh.Config()
conf.insert_json5("mode", '"client"')
conf.insert_json5("connect/endpoints", f'["{endpoint}"]')
conf.insert_json5("scouting/multicast/enabled", "false")
conf.insert_json5("transport/shared_memory/enabled", "false")
s = zenoh.open(conf)
ents = []
if "token" in decl:
    ents.append(s.liveliness().declare_token(f"vs/probe/alive/a{n}"))
if "sub" in decl:
    ents.append(s.declare_subscriber("vs/probe/frame/**", lambda _s: None))
if "usub" in decl:   # a subscriber on a new key each time, as the fuzzer's barrier (vsfuzz/<zid>/barrier)
    ents.append(s.declare_subscriber(f"vsfuzz/{s.zid()}/barrier", lambda _s: None))
if "queryable" in decl:
    ents.append(s.declare_queryable(f"vs/probe/peer/a{n}/health", lambda q: q.reply(q.key_expr, b"ok")))
for i in range(30):
    s.put(f"vs/probe/state/a{n}", b"x" * 200)
stop = []
signal.signal(signal.SIGTERM, lambda *_: stop.append(1))
print("up", flush=True)
while not stop:
    time.sleep(0.05)
for e in ents:
    e.undeclare()
s.close()
"""


def mem(pid: int) -> dict[str, float]:
    out = {}
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        k, _, v = line.partition(":")
        if k in ("VmRSS", "RssAnon", "RssShmem", "Threads"):
            out[k] = float(v.split()[0]) / (1024.0 if k != "Threads" else 1.0)
    return out


def client_conf(endpoint: str):
    import zenoh
    conf = zenoh.Config()
    conf.insert_json5("mode", '"client"')
    conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("transport/shared_memory/enabled", "false")
    return conf


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--mode", choices=["none", "kill", "close", "fuzz", "fuzzlong"], required=True)
    ap.add_argument("--every", type=float, default=3.0)
    ap.add_argument("--minutes", type=float, default=5.0)
    ap.add_argument("--decl", default="token,sub,queryable",
                    help="what the kill/close child declares: any of token,sub,usub (a new key each time),queryable, or none")
    ap.add_argument("--fuzz-s", type=float, default=5.0)
    ap.add_argument("--fuzz-rate", type=float, default=30.0)
    ap.add_argument("--env", action="append", default=[], help="KEY=VALUE in the router's environment")
    ap.add_argument("--agent", action="store_true",
                    help="also a `vsfleet agent --robot r1 --fleet probe` (no mission: it rejects what the fuzzer sends "
                         "it), sampled as the router (a_* fields); --agent-env KEY=VALUE in its environment")
    ap.add_argument("--agent-env", action="append", default=[])
    args = ap.parse_args(argv)

    import zenoh
    from vsfleet.fleetctl.router import free_loopback_port, wait_listening
    from vsfleet.fleetctl.run import child_command
    port = free_loopback_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    env = dict(os.environ, **dict(e.split("=", 1) for e in args.env))
    quiet = dict(stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, stdin=subprocess.DEVNULL)
    router = subprocess.Popen(child_command("router", "--listen", endpoint, "--no-multicast-scouting"), env=env,
                              start_new_session=True, **quiet)
    wait_listening(port, 20.0)
    agent = None
    if args.agent:
        from vsfleet.zglue.zconf import zenoh_flags
        aenv = dict(os.environ, **dict(e.split("=", 1) for e in args.agent_env))
        agent_cmd = child_command("agent", "--robot", "r1", "--fleet", "probe", *zenoh_flags(endpoint))
        agent = subprocess.Popen(agent_cmd, env=aenv, start_new_session=True, **quiet)
    t0 = time.time()
    sink = zenoh.open(client_conf(endpoint))
    got = [0]
    subs = [sink.declare_subscriber("vs/probe/**", lambda _s: got.__setitem__(0, got[0] + 1)),
            sink.liveliness().declare_subscriber("vs/probe/alive/**", lambda _s: None, history=True)]
    pub = zenoh.open(client_conf(endpoint))
    stop = threading.Event()

    def traffic():
        k = 0
        while not stop.is_set():
            pub.put("vs/probe/frame/sim", b"f" * 120)
            k += 1
            stop.wait(max(0.0, t0 + k / 30.0 - time.time()))
    threading.Thread(target=traffic, daemon=True).start()

    fuzz_cmd = lambda dur, seed: child_command(  # noqa: E731
        "fuzz", "--fleet", "probe", "--kinds", "frame,mission,cmd,fault", "--rate", str(args.fuzz_rate),
        "--duration", f"{dur:.1f}", "--robots", "r1,r2,r3", "--seed", str(seed), "--connect", endpoint,
        "--no-multicast-scouting")
    long_fuzz = None
    if args.mode == "fuzzlong":
        long_fuzz = subprocess.Popen(fuzz_cmd(args.minutes * 60.0, 1), **quiet)
    end = t0 + args.minutes * 60.0
    done, n = 0, 0
    next_inj, next_sample = t0 + 10.0, t0
    rows = []
    running: subprocess.Popen | None = None
    while time.time() < end:
        now = time.time()
        if now >= next_sample:
            m = mem(router.pid)
            row = {"t": round(now - t0, 1), "done": done, "got": got[0], **{k: round(v, 3) for k, v in m.items()},
                   "load": Path("/proc/loadavg").read_text().split()[0]}
            if agent is not None and agent.poll() is None:
                row.update({f"a_{k}": round(v, 3) for k, v in mem(agent.pid).items()})
            rows.append(row)
            print(json.dumps(row), flush=True)
            next_sample += 2.0
        if args.mode in ("kill", "close", "fuzz") and now >= next_inj and running is None:
            n += 1
            if args.mode == "fuzz":
                running = subprocess.Popen(fuzz_cmd(args.fuzz_s, n), **quiet)
            else:
                running = subprocess.Popen([sys.executable, "-c", CHILD, str(n), endpoint, args.decl],
                                           stdout=subprocess.PIPE, stderr=subprocess.DEVNULL,
                                           stdin=subprocess.DEVNULL)
                running.stdout.readline()  # "up": its session is open and declared
                time.sleep(1.0)
                running.send_signal(signal.SIGKILL if args.mode == "kill" else signal.SIGTERM)
            next_inj = now + args.every
        if running is not None and running.poll() is not None:
            running, done = None, done + 1
        time.sleep(0.05)
    stop.set()
    for p in (running, long_fuzz, agent):
        if p is not None and p.poll() is None:
            p.kill()
            p.wait()
    for s in subs:
        s.undeclare()
    sink.close()
    pub.close()
    router.send_signal(signal.SIGTERM)
    try:
        router.wait(10)
    except subprocess.TimeoutExpired:
        router.kill()

    def at(t):
        return min(rows, key=lambda r: abs(r["t"] - t))
    a, mid, z = at(30.0), at(args.minutes * 30.0), rows[-1]
    per = (z["RssAnon"] - mid["RssAnon"]) / (z["done"] - mid["done"]) if z["done"] > mid["done"] else None
    print(json.dumps({"mode": args.mode, "decl": args.decl, "every": args.every, "env": args.env, "minutes": args.minutes,
                      "injections": z["done"], "anon_30s": a["RssAnon"], "anon_mid": mid["RssAnon"],
                      "anon_end": z["RssAnon"], "rss_30s": a["VmRSS"], "rss_end": z["VmRSS"],
                      "anon_growth_2nd_half": round(z["RssAnon"] - mid["RssAnon"], 3),
                      "anon_per_injection_2nd_half_kib": None if per is None else round(per * 1024, 1),
                      "threads": z.get("Threads"), "load_end": z["load"],
                      **({"agent_anon_30s": a.get("a_RssAnon"), "agent_anon_mid": mid.get("a_RssAnon"),
                          "agent_anon_end": z.get("a_RssAnon"), "agent_env": args.agent_env} if agent else {})}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
