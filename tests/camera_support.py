"""What the camera tests share: the deploy camera config, robot poses to draw, the rendered camera and its
calibration (as module-scoped fixtures), and running a `vsfleet` child command.

Needs OpenCV: import it after ``pytest.importorskip("cv2")``. A test module takes the fixtures config,
renderer and calibration by importing them (``from camera_support import config_fixture, ...``; the
``_fixture`` names keep test arguments from shadowing the imports). tests/ is on sys.path for the tests below
it (rootdir-based imports, tests/ has no __init__.py), tests/integration included.
"""

from __future__ import annotations

import copy
import subprocess
from pathlib import Path

import numpy as np
import pytest

from vsfleet.fleetctl.run import child_command
from vsfleet.tracker.calib import FloorCalibration
from vsfleet.tracker.calibrate import calibrate_frames
from vsfleet.tracker.markers import CameraConfig, load_config
from vsfleet.tracker.render import Renderer, SimCameraSpec, reference_scene, robot_scene, sim_camera_from_dict

ROOT = Path(__file__).parent.parent
CONFIG = ROOT / "deploy" / "camera" / "overhead.toml"
TRUTH = {"r1": (0.3, 0.02, 0.0), "r2": (-0.16, 0.25, 0.2), "r3": (-0.13, -0.27, -0.1)}


_PRISTINE: dict[tuple[str, str], Renderer] = {}


def fresh_renderer(spec: SimCameraSpec, dictionary: str) -> Renderer:
    """A Renderer in the very state ``Renderer(spec, dictionary)`` starts in, without making its images again.

    Making a Renderer costs ~0.5 s of CPU (the floor seen through every pixel, the vignette, the noise banks); the
    camera tests made 17 of a few specs. The first one of a spec is kept unused (its arrays read-only: render only
    reads them, and a write would raise) and each call returns a shallow copy of it with its own random generator
    at the state a new one's has, and its own marker-texture cache: the same frames, bit for bit."""
    key = (repr(spec), dictionary)
    pristine = _PRISTINE.get(key)
    if pristine is None:
        pristine = Renderer(spec, dictionary)
        for value in vars(pristine).values():
            for array in (value if isinstance(value, list) else [value]):
                if isinstance(array, np.ndarray):
                    array.flags.writeable = False
        _PRISTINE[key] = pristine
    out = copy.copy(pristine)
    out.rng = copy.deepcopy(pristine.rng)
    out.textures = dict(pristine.textures)
    return out


def renderer_for(config: CameraConfig) -> Renderer:
    """The synthetic camera of ``config`` (its sim_camera section), as Renderer makes it."""
    return fresh_renderer(sim_camera_from_dict(config.sim_camera), config.dictionary)


def frame_of(config: CameraConfig, poses_world: dict, t_s: float = 0.0, spec: SimCameraSpec | None = None):
    """vsfleet.tracker.render.render_frame (a new Renderer's one frame of the robots at ``poses_world``) on a
    fresh_renderer: the same image."""
    spec = spec or sim_camera_from_dict(config.sim_camera)
    return fresh_renderer(spec, config.dictionary).render(robot_scene(config, spec, poses_world), t_s)


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
