"""The camera commands without OpenCV installed: a one-line hint, not a traceback (runs without cv2)."""

from __future__ import annotations

import subprocess
import sys

import pytest

# A child interpreter in which `import cv2` fails as it does when the camera extra is not installed.
WITHOUT_CV2 = ("import sys; sys.modules['cv2'] = None; from fleetctl.cli import main; "
               "raise SystemExit(main(sys.argv[1:]))")


@pytest.mark.parametrize("command", [["tracker", "camera", "--help"], ["tracker", "calibrate", "--help"],
                                     ["render", "--help"], ["tracker", "camera", "--camera", "x.toml"]])
def test_a_camera_command_without_opencv_says_how_to_install_it(command):
    out = subprocess.run([sys.executable, "-c", WITHOUT_CV2, *command], capture_output=True, text=True,
                         timeout=60, stdin=subprocess.DEVNULL)
    assert out.returncode == 2, out.stderr
    assert "install vsfleet[camera] (pip install '.[camera]')" in out.stderr
    assert "Traceback" not in out.stderr and "ModuleNotFoundError" not in out.stderr


def test_other_commands_do_not_need_opencv():
    out = subprocess.run([sys.executable, "-c", WITHOUT_CV2, "tracker", "sim", "--help"], capture_output=True,
                         text=True, timeout=60, stdin=subprocess.DEVNULL)
    assert out.returncode == 0, out.stderr
    assert "vsfleet tracker sim" in out.stdout
