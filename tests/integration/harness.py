"""The shared harness lives in conftest.py (one copy); this name is kept for tests that import it from here."""

from .conftest import LoopbackFleet, Observed, free_loopback_port, open_client, start_fleet, wait_port  # noqa: F401
