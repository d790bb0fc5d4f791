"""The embedded router: loopback, multicast off, admin space on."""

import json

import pytest
import zenoh

from vsfleet.fleetctl.router import open_loopback_router

pytestmark = pytest.mark.integration


def test_the_embedded_routers_admin_space_shows_sessions_and_liveliness_tokens():
    router, endpoint = open_loopback_router()
    conf = zenoh.Config()
    conf.insert_json5("mode", '"client"')
    conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    try:
        with zenoh.open(conf) as client:
            token = client.liveliness().declare_token("vs/demo/alive/agent/r1")
            keys = [str(r.ok.key_expr) for r in client.get("@/**", timeout=5) if r.ok is not None]
            token.undeclare()
    finally:
        router.close()
    assert any(k.endswith("/router/token/vs/demo/alive/agent/r1") for k in keys), keys
    assert any("/session/transport/unicast/" in k for k in keys), keys
