"""Loading scenario files from disk (the I/O half of vsfleet.scenario)."""

from __future__ import annotations

import dataclasses
import tomllib
from pathlib import Path

from vsfleet.scenario import Scenario, ScenarioError, scenario_from_dict
from vsfleet.wire import WireError, check_name


def load_scenario(path: str | Path, fleet: str | None = None) -> Scenario:
    """Read and validate a scenario TOML file; ``fleet`` overrides its fleet name."""
    path = Path(path)
    try:
        doc = tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as exc:
        raise ScenarioError(f"{path}: not valid TOML: {exc}") from None
    scenario = scenario_from_dict(doc, name=path.stem)
    if fleet is not None:
        try:
            check_name(fleet, "fleet")
        except WireError as exc:
            raise ScenarioError(str(exc)) from None
        scenario = dataclasses.replace(scenario, fleet=fleet)
    return scenario
