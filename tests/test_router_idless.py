"""EmbeddedRouter's declarations declare no key-expression id, and deliver only what the plain key matches.

Why the key is widened (``vs/demo/**`` → ``*/demo/**``): fleetctl.router.EmbeddedRouter; the close behind
the input is tests/integration/test_zenoh_errors.py. Here: what reaches the callback, in one process.
"""

from __future__ import annotations

import threading
from types import SimpleNamespace

import zenoh

from vsfleet.fleetctl.router import EmbeddedRouter, client_config, idless, open_loopback_router


def test_a_literal_first_chunk_becomes_a_star_and_the_callback_sees_only_the_plain_keys_samples():
    got = []
    key, deliver = idless("vs/demo/**", got.append)
    assert key == "*/demo/**"
    for k in ("vs/demo/frame/tracker", "vx/demo/frame/tracker", "vs/demo", "vsx/demo/a", "v/demo/a"):
        deliver(SimpleNamespace(key_expr=zenoh.KeyExpr(k)))
    assert [str(s.key_expr) for s in got] == ["vs/demo/frame/tracker", "vs/demo"]


def test_a_single_chunk_key_and_a_wild_first_chunk():
    got = []
    key, deliver = idless("vs", got.append)
    assert key == "*"
    deliver(SimpleNamespace(key_expr="vs"))
    deliver(SimpleNamespace(key_expr="vx"))
    assert [s.key_expr for s in got] == ["vs"]
    assert idless("*/demo/**", got.append) == ("*/demo/**", got.append)
    assert idless("$*s/demo", got.append) == ("$*s/demo", got.append)


def test_a_query_is_answered_when_its_key_intersects_the_plain_key():
    got = []
    key, answer = idless("vs/demo/mission", got.append, query=True)
    assert key == "*/demo/mission"
    for k in ("vs/demo/mission", "**", "*/demo/mission", "vs/**", "xx/demo/mission", "vs/other/mission"):
        answer(SimpleNamespace(key_expr=zenoh.KeyExpr(k)))
    assert [str(q.key_expr) for q in got] == ["vs/demo/mission", "**", "*/demo/mission", "vs/**"]


def test_through_a_real_router_the_subscription_the_liveliness_and_the_queryable_answer_as_the_plain_key():
    router, endpoint = open_loopback_router()
    try:
        assert isinstance(router, EmbeddedRouter)
        samples, tokens, lock = [], [], threading.Lock()
        arrived, alive = threading.Event(), threading.Event()

        def on_sample(s):
            with lock:
                samples.append(str(s.key_expr))
            if str(s.key_expr) == "vs/demo/last":
                arrived.set()

        router.declare_subscriber("vs/demo/**", on_sample)
        router.liveliness().declare_subscriber("vs/demo/alive/*", lambda s: (tokens.append(str(s.key_expr)),
                                                                              alive.set()), history=True)
        router.declare_queryable("vs/demo/mission", lambda q: q.reply("vs/demo/mission", b"m"), complete=True)
        client = zenoh.open(client_config(endpoint))
        try:
            client.put("vx/demo/a", b"no")
            client.put("vs/demo/a", b"yes")
            client.put("vs/demo/last", b"yes")
            assert arrived.wait(10.0)
            assert samples == ["vs/demo/a", "vs/demo/last"]
            token = client.liveliness().declare_token("vs/demo/alive/r1")
            assert alive.wait(10.0) and tokens == ["vs/demo/alive/r1"]
            replies = list(client.get("vs/demo/mission", timeout=10.0))
            assert [bytes(r.ok.payload) for r in replies] == [b"m"]
            assert list(client.get("xx/demo/mission", timeout=2.0)) == []
            token.undeclare()
        finally:
            client.close()
    finally:
        router.close()

