"""The pure core never imports zenoh, time, logging or cv2 (I/O and OpenCV stay at the edges)."""

import ast
from pathlib import Path

import pytest

FORBIDDEN = {"zenoh", "time", "logging", "socket", "threading", "cv2"}
ROOT = Path(__file__).parent.parent
CORE = sorted((ROOT / "vsfleet").rglob("*.py"))


@pytest.mark.parametrize("path", CORE, ids=lambda p: str(p.relative_to(ROOT)))
def test_core_module_imports_no_io(path):
    tree = ast.parse(path.read_text())
    imported = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            imported |= {a.name.split(".")[0] for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            imported.add(node.module.split(".")[0])
    assert not imported & FORBIDDEN, f"{path.name} imports {imported & FORBIDDEN}"


PROGRAMS = ("agent", "simfleet", "tracker", "fleetctl", "zglue")  # installed as vsfleet.agent, vsfleet.fleetctl, ...
SOURCES = sorted(p for d in ("vsfleet", *PROGRAMS, "bench", "tests") for p in (ROOT / d).rglob("*.py"))


@pytest.mark.parametrize("path", SOURCES, ids=lambda p: str(p.relative_to(ROOT)))
def test_programs_are_imported_under_the_vsfleet_namespace(path):
    """An import of a top-level agent / fleetctl / ... would work in the repository and fail installed."""
    tree = ast.parse(path.read_text())
    bad = []
    for node in ast.walk(tree):
        names = ([a.name for a in node.names] if isinstance(node, ast.Import)
                 else [node.module] if isinstance(node, ast.ImportFrom) and node.module and node.level == 0 else [])
        bad += [n for n in names if n.split(".")[0] in PROGRAMS]
    assert not bad, f"{path.relative_to(ROOT)} imports {bad}: use vsfleet.{bad[0]}"
