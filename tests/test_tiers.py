"""The suite's tiers (tests/conftest.py): the fleet tier's modules are there, and each runs a simulated fleet."""

from __future__ import annotations

from pathlib import Path

from conftest import FLEET_MODULES

HERE = Path(__file__).parent


def test_every_module_of_the_fleet_tier_exists_and_runs_a_fleet_offline():
    for name in FLEET_MODULES:
        path = HERE / name
        assert path.is_file(), f"{name} is in FLEET_MODULES but not in tests/"
        assert "run_offline" in path.read_text(), f"{name} runs no simulated fleet: it belongs to the unit tier"
