"""What the camera tests share: the deploy camera config, robot poses to draw, the rendered camera and its
calibration (as module-scoped fixtures), and running a `vsfleet` child command.

Needs OpenCV: import it after ``pytest.importorskip("cv2")``. A test module takes the fixtures config,
renderer and calibration by importing them (``from camera_support import config_fixture, ...``; the
``_fixture`` names keep test arguments from shadowing the imports). tests/ is on sys.path for the tests below
it (rootdir-based imports, tests/ has no __init__.py), tests/integration included.
"""

from __future__ import annotations

import subprocess
from pathlib import Path

import pytest

from vsfleet.fleetctl.run import child_command
from vsfleet.tracker.calib import FloorCalibration
from vsfleet.tracker.calibrate import calibrate_frames
from vsfleet.tracker.markers import CameraConfig, load_config
from vsfleet.tracker.render import Renderer, reference_scene, sim_camera_from_dict

ROOT = Path(__file__).parent.parent
CONFIG = ROOT / "deploy" / "camera" / "overhead.toml"
TRUTH = {"r1": (0.3, 0.02, 0.0), "r2": (-0.16, 0.25, 0.2), "r3": (-0.13, -0.27, -0.1)}


def renderer_for(config: CameraConfig) -> Renderer:
    """The synthetic camera of ``config`` (its sim_camera section)."""
    return Renderer(sim_camera_from_dict(config.sim_camera), config.dictionary)


def calibrate_rendered(config: CameraConfig, renderer: Renderer) -> FloorCalibration:
    """The calibration from one rendered frame of the config's reference markers."""
    return calibrate_frames([renderer.render(reference_scene(config), 0.0)], config, renderer.camera.intrinsics)


def save_calibration(camera: Path, out: Path) -> CameraConfig:
    """Calibrate the camera config at ``camera`` on its rendered references, save to ``out``; its config."""
    config = load_config(camera)
    calibrate_rendered(config, renderer_for(config)).save(out)
    return config


@pytest.fixture(scope="module", name="config")
def config_fixture() -> CameraConfig:
    return load_config(CONFIG)


@pytest.fixture(scope="module", name="renderer")
def renderer_fixture(config) -> Renderer:
    return renderer_for(config)


@pytest.fixture(scope="module", name="calibration")
def calibration_fixture(config, renderer) -> FloorCalibration:
    return calibrate_rendered(config, renderer)


def run_cli(*args, timeout=60):
    return subprocess.run(child_command(*args), capture_output=True, text=True, timeout=timeout,
                          stdin=subprocess.DEVNULL)
