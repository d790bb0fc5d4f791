"""The agent step's records for the core's golden vectors (tests/golden_core.py): filled in once the
whole step runs in the core (vsfleet/_core/vs_step.c)."""


def step_records() -> list[tuple[str, list[float]]]:
    return []
