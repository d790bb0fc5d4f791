"""Zenoh access control on the deployed router: rogue clients move nothing; the fleet still runs.

The router is `vsfleet router --config` with the config `vsfleet deploy config`
writes (usrpwd dictionary, or mTLS with certificates made by the openssl CLI).
Rogue payloads are valid messages with an extra ``rogue`` field (receivers
ignore unknown fields), so one that got through would act, and is counted.
"""

from __future__ import annotations

import dataclasses
import shutil
import subprocess
import threading
import time
from pathlib import Path

import msgpack
import pytest
import zenoh

from fleetctl.deploy import make_certs
from fleetctl.run import child_command
from vsfleet.analysis import agreement
from vsfleet.wire import CmdMsg, FaultMsg, PoseMsg, TruthMsg, encode, encode_mission

from .secured import SecuredFleet

pytestmark = pytest.mark.integration

# keeps driving a circle, so "the robots still move" is always observable
CIRCLE = Path(__file__).parent.parent / "data" / "deploy-circle.toml"
TRIES_PER_KEY = 20
ROGUE_TOKEN = zenoh.KeyExpr("vs/lab/alive/*/r9")


def marked(payload: bytes, who: str) -> bytes:
    """The same message with a ``rogue`` field that identifies the sender."""
    m = msgpack.unpackb(payload)
    m["rogue"] = who
    return msgpack.packb(m, use_bin_type=True)


class RogueCounter:
    """Every sample under the fleet's key space that carries a ``rogue`` field, by sender."""

    def __init__(self) -> None:
        self.cond = threading.Condition()
        self.got: list[tuple[str, str]] = []  # (sender, key)
        self.sentinels: set[str] = set()
        self.tokens: list[str] = []  # liveliness tokens of robots no mission names

    def on_token(self, sample: zenoh.Sample) -> None:
        if sample.key_expr.intersects(ROGUE_TOKEN) and sample.kind == zenoh.SampleKind.PUT:
            with self.cond:
                self.tokens.append(str(sample.key_expr))

    def on_sample(self, sample: zenoh.Sample) -> None:
        if sample.kind == zenoh.SampleKind.DELETE:  # nobody in the fleet deletes: a rogue's
            with self.cond:
                self.got.append(("delete", str(sample.key_expr)))
            return
        try:
            m = msgpack.unpackb(sample.payload.to_bytes())
        except Exception:  # noqa: BLE001 - not ours
            return
        if isinstance(m, dict) and "rogue" in m:
            with self.cond:
                if "sentinel" in m:
                    self.sentinels.add(m["rogue"])
                else:
                    self.got.append((m["rogue"], str(sample.key_expr)))
                self.cond.notify_all()

    def wait_sentinel(self, who: str, timeout_s: float) -> None:
        with self.cond:
            if not self.cond.wait_for(lambda: who in self.sentinels, timeout=timeout_s):
                raise TimeoutError(f"the sentinel of {who} did not arrive within {timeout_s} s")


def moving(robot: str, after_t: float):
    def pred(obs):
        return any(r == robot and m.t > after_t and abs(m.vl) + abs(m.vr) > 0.02 for _, r, m in obs.truth[-60:])
    return pred


def rogue_messages(fleet: SecuredFleet, who: str) -> list[tuple[str, bytes]]:
    """(key, payload) a rogue tries: drive r1, change the mission, inject poses, faults, truth
    (less what the login ``who`` may legitimately put)."""
    k, now = fleet.keys, time.time()
    evil_mission = dataclasses.replace(fleet.mission, version=int(now * 1000) + 10**6, twist=None,
                                       goal=(-2.0, -2.0, 3.0), effective_t=now)  # newer than the real one
    msgs = [
        (k.cmd("r1"), encode(CmdMsg(t=now, seq=10**6, vl=0.3, vr=-0.3, ttl=5.0))),
        (k.mission, encode_mission(evil_mission)),
        (k.pose("r1"), encode(PoseMsg(t=now, seq=10**6, x=5.0, y=5.0, th=0.0, src="rogue"))),
        (k.fault("r1"), encode(FaultMsg(kind="stop", factor=0.0, duration=0.0))),
        (k.truth("r1"), encode(TruthMsg(t=now, x=5.0, y=5.0, th=0.0, vl=0.0, vr=0.0))),
    ]
    own = {"tracker": k.pose("r1"), "sim": k.truth("r1")}.get(who)  # what that login may put
    return [(key, marked(p, who)) for key, p in msgs if key != own]


def sentinel(fleet: SecuredFleet, who: str) -> tuple[str, bytes]:
    """A harmless message ``who`` may put: its own state, or a valid pose/truth of robot zz,
    which no mission names (agents ignore it, nobody rejects it)."""
    k, now = fleet.keys, time.time()
    key, msg = {"tracker": (k.pose("zz"), PoseMsg(t=now, seq=0, x=0.0, y=0.0, th=0.0, src="rogue")),
                "sim": (k.truth("zz"), TruthMsg(t=now, x=0.0, y=0.0, th=0.0, vl=0.0, vr=0.0))}.get(
        who, (k.state(who), {"t": now}))
    m = msgpack.unpackb(encode(msg)) if not isinstance(msg, dict) else msg
    return key, msgpack.packb({**m, "rogue": who, "sentinel": True}, use_bin_type=True)


def attack(fleet: SecuredFleet, session: zenoh.Session, who: str) -> tuple[int, zenoh.LivelinessToken]:
    """Put every rogue message TRIES_PER_KEY times (also on wildcard keys), declare a token
    for robot r9, then put a sentinel on a key this identity may use; returns (tried, token)."""
    tried = 0
    cmd = rogue_messages(fleet, who)[0][1]
    for _ in range(TRIES_PER_KEY):
        for key, payload in rogue_messages(fleet, who):
            session.put(key, payload)
            tried += 1
        for key in (fleet.keys.cmd("*"), fleet.keys.everything):
            session.put(key, cmd)
            tried += 1
        session.delete(fleet.keys.cmd("r1"))
        tried += 1
    token = session.liveliness().declare_token(fleet.keys.alive("agent", "r9"))
    tried += 1
    session.put(*sentinel(fleet, who))
    return tried, token


def refused(fleet: SecuredFleet, conf: zenoh.Config) -> bool:
    """True when the router refuses the session (the rogue cannot even connect)."""
    conf.insert_json5("connect/timeout_ms", "3000")
    conf.insert_json5("connect/exit_on_failure", "true")
    try:
        session = zenoh.open(conf)
    except zenoh.ZError:
        return True
    try:  # connected after all: try everything, the counter will see what got through
        attack(fleet, session, "unauthenticated")[1].undeclare()
    finally:
        session.close()
    return False


def anonymous_configs(fleet: SecuredFleet, tmp: Path) -> dict[str, zenoh.Config]:
    """Sessions with no valid login: no credentials, a wrong password or a foreign certificate."""
    out = {}
    for mode in ("client", "peer"):
        c = zenoh.Config()
        c.insert_json5("mode", f'"{mode}"')
        c.insert_json5("connect/endpoints", f'["{fleet.endpoint}"]')
        c.insert_json5("scouting/multicast/enabled", "false")
        out[f"no login ({mode})"] = c
    if fleet.auth == "usrpwd":
        c = zenoh.Config.from_file(str(fleet.client_config("r1")))
        c.insert_json5("transport/auth/usrpwd/password", '"guessed"')
        out["r1 with a wrong password"] = c
    else:
        make_certs(tmp / "foreign-pki", ["127.0.0.1"], ("r1",))
        c = zenoh.Config.from_file(str(fleet.client_config("r1")))
        for key, f in (("root_ca_certificate", "ca.pem"), ("connect_certificate", "r1.pem"),
                       ("connect_private_key", "r1.key")):
            c.insert_json5(f"transport/link/tls/{key}", f'"{tmp / "foreign-pki" / f}"')
        out["r1 with a certificate from another CA"] = c
        c = zenoh.Config.from_file(str(fleet.client_config("r1")))
        c.insert_json5("transport/link/tls/connect_certificate", "null")
        c.insert_json5("transport/link/tls/connect_private_key", "null")
        out["TLS without a client certificate"] = c
    return out


@pytest.fixture(params=["usrpwd", "mtls"])
def fleet(request, tmp_path):
    if request.param == "mtls" and shutil.which("openssl") is None:
        pytest.skip("mTLS needs the openssl command-line tool to make certificates")
    f = SecuredFleet(CIRCLE, tmp_path, auth=request.param)
    yield f
    f.close()


def test_rogue_clients_cannot_move_a_robot_change_the_mission_or_inject_poses(fleet, tmp_path):
    counter = RogueCounter()
    watch = fleet.router.declare_subscriber(fleet.keys.everything, counter.on_sample)
    watch_tokens = fleet.router.liveliness().declare_subscriber(fleet.keys.alive(), counter.on_token)
    fleet.start_sim_and_tracker()
    fleet.start_agent("r1")
    fleet.start_agent("r2")
    fleet.wait_alive("agent", ("r1", "r2"))
    # the operator publishes the mission with the documented command and its own login
    # (--force: r3's agent is not up yet, on purpose)
    out = subprocess.run(child_command("mission", "set", str(CIRCLE), "--fleet", fleet.keys.fleet, "--delay", "0",
                                       "--force",
                                       "--config", str(fleet.client_config("operator"))),
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    fleet.observed.wait_for(moving("r1", 0.0), timeout_s=20)
    version = fleet.observed.wait_for(lambda o: next((m.mission for _, _, m in o.state), None), timeout_s=10)
    # a late agent gets the mission by query from r1/r2's queryables, through the ACL
    fleet.start_agent("r3")
    fleet.observed.wait_for(
        lambda o: any(r == "r3" and "r3" in m.used for _, r, m in o.state), timeout_s=20)

    # 1. no valid login: the router refuses the session at the handshake
    outcomes = {label: refused(fleet, conf) for label, conf in anonymous_configs(fleet, tmp_path).items()}
    # 2. valid logins that may not do these things: another robot, the tracker, the simulator
    tried = {}
    t_attack = time.time()
    for who in ("r2", "tracker", "sim"):
        with fleet.open_as(who) as s:
            tried[who], token = attack(fleet, s, who)
            counter.wait_sentinel(who, timeout_s=10)  # everything before it has been routed
            # the router's own token table, asked while the rogue's token is still declared
            tokens = [str(r.ok.key_expr) for r in fleet.router.liveliness().get(ROGUE_TOKEN, timeout=5)
                      if r.ok is not None]
            counter.tokens.extend(tokens)
            token.undeclare()
    print(f"auth {fleet.auth}: sessions refused: {outcomes}")
    print(f"auth {fleet.auth}: rogue messages tried {tried} (total {sum(tried.values())}), "
          f"reached a subscriber: {len(counter.got)} {counter.got[:5]}")
    assert all(outcomes.values()), outcomes
    assert counter.got == []
    assert counter.tokens == []

    # the legitimate fleet still works: every robot moves, every agent publishes state on mission v1
    for r in ("r1", "r2", "r3"):
        fleet.observed.wait_for(moving(r, t_attack), timeout_s=10)
    fleet.observed.wait_for(
        lambda o: {r for t, r, _ in o.state if t > t_attack + 0.5} == {"r1", "r2", "r3"}, timeout_s=10)
    late = [(r, m) for t, r, m in fleet.observed.state if t > t_attack]
    assert late and all(m.mission == version and m.rejected == 0 for _, m in late)
    a = agreement(late, min_agents=3)
    assert a.frames > 10 and a.identical == a.frames
    watch.undeclare()
    watch_tokens.undeclare()
