"""`vsfleet run --foxglove PORT` serves the running fleet to a Foxglove client and says where."""

from __future__ import annotations

import signal
import subprocess
import sys
import threading
from pathlib import Path

import pytest

from tests.foxglove_support import UNKNOWN_CHANNEL_LOG, FoxgloveClient
from vsfleet.fleetctl.router import free_loopback_port
from vsfleet.fleetctl.router import wait_listening as wait_port

E2E = Path(__file__).parent.parent / "data" / "e2e-triangle.toml"


# the port probe; foxglove-sdk's advertise race (tests/foxglove_support.py: the client subscribes again)
@pytest.mark.provokes_errors(r"foxglove\.websocket\.server ERROR Dropping client .*: handshake failed",
                             UNKNOWN_CHANNEL_LOG)
def test_run_with_foxglove_prints_the_address_and_a_client_sees_the_fleets_scene(tmp_path):
    port = free_loopback_port()
    proc = subprocess.Popen([sys.executable, "-m", "vsfleet.fleetctl.cli", "run", str(E2E), "--duration", "60",
                             "--no-stop-at-goal", "--out", str(tmp_path), "--foxglove", str(port)],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, start_new_session=True)
    lines: list[str] = []
    said = threading.Event()

    def read() -> None:
        for line in proc.stdout:
            lines.append(line)
            if f"ws://127.0.0.1:{port}" in line:
                said.set()

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    client = None
    try:
        assert said.wait(60), "".join(lines)
        wait_port(port, 30.0)
        client = FoxgloveClient(f"ws://127.0.0.1:{port}")
        scene = "/foxglove/vs/e2e/scene"  # the scenario's fleet
        client.wait_for(lambda c: scene in c.topics(), 30)
        client.subscribe([scene])
        client.wait_for(lambda c: len(c.messages[scene]) >= 5, 60)
        ids = {e["id"] for _, update in client.messages[scene] for e in update.get("entities", [])}
        print("scene entities:", sorted(ids))
        assert {"robots", "fitted", "advanced"} <= ids, ids
    finally:
        if client is not None:
            client.close()
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(timeout=30)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
        reader.join(timeout=5)
