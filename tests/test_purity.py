"""The pure core never imports zenoh, time, logging or cv2 (I/O and OpenCV stay at the edges)."""

import ast
from pathlib import Path

import pytest

FORBIDDEN = {"zenoh", "time", "logging", "socket", "threading", "cv2"}
CORE = sorted((Path(__file__).parent.parent / "vsfleet").glob("*.py"))


@pytest.mark.parametrize("path", CORE, ids=lambda p: p.name)
def test_core_module_imports_no_io(path):
    tree = ast.parse(path.read_text())
    imported = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            imported |= {a.name.split(".")[0] for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            imported.add(node.module.split(".")[0])
    assert not imported & FORBIDDEN, f"{path.name} imports {imported & FORBIDDEN}"
