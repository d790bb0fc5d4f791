"""Two cameras over one floor: two `vsfleet tracker camera --source render` processes, each with its own
src and calibration, draw the fleet's truth through two different simulated cameras whose views overlap
(deploy/camera/overhead.toml and overhead-2.toml). The agents merge them (freshest pose per robot by
(t, seq); complete only within one (src, seq)) and close the loop on tests/data/e2e-triangle.toml.
"""

from __future__ import annotations

import threading
from pathlib import Path

import pytest

cv2 = pytest.importorskip("cv2")

from tracker.calibrate import calibrate_frames  # noqa: E402
from tracker.markers import load_config  # noqa: E402
from tracker.render import Renderer, reference_scene, sim_camera_from_dict  # noqa: E402
from vsfleet.analysis import deviation_stats, fitted_truth, goal_distance, truth_frames  # noqa: E402
from vsfleet.wire import decode_pose  # noqa: E402

from .harness import LoopbackFleet  # noqa: E402
from .test_camera_loop import GOAL_TOL_M, MAX_DEVIATION_M, settled  # noqa: E402

pytestmark = pytest.mark.integration

ROOT = Path(__file__).parent.parent.parent
E2E = ROOT / "tests" / "data" / "e2e-triangle.toml"
CAMERAS = [ROOT / "deploy" / "camera" / "overhead.toml", ROOT / "deploy" / "camera" / "overhead-2.toml"]


def calibrate(path: Path, out: Path):
    config = load_config(path)
    renderer = Renderer(sim_camera_from_dict(config.sim_camera), config.dictionary)
    calibrate_frames([renderer.render(reference_scene(config), 0.0)], config,
                     renderer.camera.intrinsics).save(out)
    return config


def test_two_cameras_with_their_own_src_drive_the_fleet_in_formation_to_its_goal(tmp_path):
    configs = [calibrate(p, tmp_path / f"cal-{p.stem}.json") for p in CAMERAS]
    srcs = [c.src for c in configs]
    assert len(set(srcs)) == 2

    fleet = LoopbackFleet(E2E, tmp_path)
    poses, lock = [], threading.Lock()

    def on_pose(sample):
        robot = fleet.keys.robot_of(str(sample.key_expr), "pose")
        msg = decode_pose(sample.payload.to_bytes())
        with lock:
            poses.append((robot, msg))

    pose_sub = fleet.router.declare_subscriber(fleet.keys.pose(), on_pose)
    robots = fleet.mission.robot_ids
    try:
        fleet.start("sim", "sim", str(E2E))
        for path, config in zip(CAMERAS, configs):
            fleet.start(f"tracker-{config.src}", "tracker", "camera", "--camera", str(path),
                        "--calibration", str(tmp_path / f"cal-{path.stem}.json"), "--source", "render",
                        "--rate", str(fleet.scenario.tracker.rate_hz), "--fleet", fleet.scenario.fleet)
        for r in robots:
            fleet.start_agent(r)
        fleet.wait_alive("agent", robots)
        fleet.wait_alive("tracker", srcs)
        fleet.publish_mission()
        at_goal = fleet.observed.wait_for(settled(fleet.mission), timeout_s=fleet.scenario.duration_s)
        states = [s for _, _, s in fleet.observed.state]
    except TimeoutError:
        pytest.fail("fleet did not settle at the goal\n" + fleet.logs())
    finally:
        pose_sub.undeclare()
        fleet.close()

    truth = [(r, m) for _, r, m in fleet.observed.truth]
    fitted = fitted_truth(fleet.mission, truth_frames(truth))
    t_first = min(s.t for s in states)
    stats = deviation_stats([f for f in fitted if f[0] >= t_first])
    for d in stats:
        print(f"{d.robot}: deviation mean {100 * d.mean_m:.2f} cm, max {100 * d.max_m:.2f} cm over {d.samples}")
    assert len(stats) == 3
    assert all(d.max_m < MAX_DEVIATION_M for d in stats), fleet.logs()
    assert goal_distance(fleet.mission, at_goal) <= GOAL_TOL_M

    with lock:
        seen = list(poses)
    # both cameras published every robot, one capture time per (src, seq), each a truth time drawn
    assert {m.src for _, m in seen} == set(srcs)
    for src in srcs:
        assert {r for r, m in seen if m.src == src} == set(robots)
    by_frame: dict[tuple[str, int], set[float]] = {}
    for _, m in seen:
        by_frame.setdefault((m.src, m.seq), set()).add(m.t)
    assert all(len(ts) == 1 for ts in by_frame.values())
    for src in srcs:  # and no truth drawn twice by one camera
        assert len({m.t for _, m in seen if m.src == src}) == sum(1 for s, _ in by_frame if s == src)
    truth_times = {m.t for _, m in truth}
    assert {m.t for _, m in seen} <= truth_times

    # the agents ran frames from both cameras: a state echoes the (t, seq) of its frame's newest pose
    src_of: dict[tuple[float, int], set[str]] = {}
    for _, m in seen:
        src_of.setdefault((m.t, m.seq), set()).add(m.src)
    ran = {src: 0 for src in srcs}
    both = unseen = 0  # both cameras drew the same truth t in a frame of the same seq; a pose the test missed
    for s in states:
        owners = src_of.get((s.t, s.seq), set())
        if len(owners) == 1:
            ran[next(iter(owners))] += 1
        elif owners:
            both += 1
        else:
            unseen += 1
    complete = sum(1 for s in states if s.complete)
    print(f"agent steps per camera: {ran} ({both} from the same (t, seq) of both, {unseen} unseen); "
          f"{complete} of {len(states)} complete; "
          f"poses per camera: { {src: sum(1 for _, m in seen if m.src == src) for src in srcs} }")
    assert all(n > 0 for n in ran.values()), ran
