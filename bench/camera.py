"""Camera tracker accuracy and speed on rendered 1280x720 frames of a 3 m x 2 m floor.

Calibrates from the rendered reference-marker frame (pinhole model with the
sim camera's intrinsics, as `vsfleet tracker calibrate --intrinsics` does),
then renders frames of three robots at random poses (lighting changing with
t, blur, noise) and compares the detected poses with the truth. Prints
position and heading error (mean, max) and the per-frame processing time
(detection + projection only, i.e. ``CameraTracker.process``) with the frame
rate it alone would allow.

Then the end-to-end figure, through the CLI path: the same kind of frames are
written to a lossless FFV1 video, and `vsfleet tracker camera --source
clip.avi --no-pace` (a child process, a client of a loopback router with a
pose subscriber) decodes, detects and publishes them as fast as it can. Its
own stats give frames / wall time from the video's open to the last publish;
the subscriber checks that the poses arrived.

    .venv/bin/python bench/camera.py [--frames 300] [--e2e-frames 300] [--config deploy/camera/overhead.toml]
"""

from __future__ import annotations

import argparse
import math
import os
import re
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from vsfleet.tracker.calibrate import calibrate_frames  # noqa: E402
from vsfleet.tracker.markers import CameraTracker, load_config  # noqa: E402
from vsfleet.tracker.render import Renderer, reference_scene, robot_scene, sim_camera_from_dict, write_video  # noqa: E402
from vsfleet.geometry import angle_diff  # noqa: E402

FLOOR_M = ((-0.4, 2.4), (-0.4, 1.4))   # robot centres inside the 3 x 2 m floor, 0.1 m from its edges
MIN_SEPARATION_M = 0.3


def random_poses(rng: np.random.Generator, robots: list[str]) -> dict[str, tuple[float, float, float]]:
    while True:
        xy = np.column_stack([rng.uniform(*FLOOR_M[0], len(robots)), rng.uniform(*FLOOR_M[1], len(robots))])
        d = np.linalg.norm(xy[:, None] - xy[None], axis=2) + np.eye(len(robots)) * 9
        if d.min() >= MIN_SEPARATION_M:
            return {r: (float(x), float(y), float(rng.uniform(-math.pi, math.pi))) for r, (x, y) in zip(robots, xy)}


def measure(config_path: str, n_frames: int, seed: int = 1) -> dict:
    config = load_config(config_path)
    spec = sim_camera_from_dict(config.sim_camera)
    renderer = Renderer(spec, config.dictionary)
    calibration = calibrate_frames([renderer.render(reference_scene(config), 0.0)], config,
                                   renderer.camera.intrinsics)
    tracker = CameraTracker(config, calibration)
    robots = sorted(m.robot for m in config.markers.values())
    rng = np.random.default_rng(seed)
    pos_err, th_err, process_s, render_s, missed = [], [], [], [], 0
    for k in range(n_frames):
        truth = random_poses(rng, robots)
        t_s = k / 30.0
        start = time.perf_counter()
        image = renderer.render(robot_scene(config, spec, truth), t_s)
        mid = time.perf_counter()
        poses = dict(tracker.process(image, t_s))
        process_s.append(time.perf_counter() - mid)
        render_s.append(mid - start)
        missed += len(set(robots) - set(poses))
        for r, m in poses.items():
            x, y, th = truth[r]
            pos_err.append(math.hypot(m.x - x, m.y - y))
            th_err.append(abs(angle_diff(m.th, th)))
    pos, th = np.array(pos_err), np.array(th_err)
    return {"frames": n_frames, "poses": len(pos), "missed": missed, "rejected": tracker.rejections.count,
            "calibration_error_mm": calibration.error_mm,
            "pos_mean_mm": 1000 * pos.mean(), "pos_p99_mm": 1000 * np.quantile(pos, 0.99),
            "pos_max_mm": 1000 * pos.max(), "th_mean_mrad": 1000 * th.mean(),
            "th_p99_mrad": 1000 * np.quantile(th, 0.99), "th_max_mrad": 1000 * th.max(),
            "process_ms_mean": 1000 * np.mean(process_s), "process_ms_p95": 1000 * np.quantile(process_s, 0.95),
            "render_ms_mean": 1000 * np.mean(render_s)}


E2E_STATS = re.compile(r"(\d+) frames in ([\d.]+) s = ([\d.]+) frames/s end to end "
                       r"\(read \+ detect \+ publish; detection ([\d.]+) ms per frame\), (\d+) poses")


def measure_end_to_end(config_path: str, n_frames: int, seed: int = 2) -> dict:
    """frames / wall time of `vsfleet tracker camera` on a rendered FFV1 video: decode + detect + publish."""
    from vsfleet.fleetctl.router import open_loopback_router
    from vsfleet.fleetctl.run import child_command
    from vsfleet.zglue.zconf import zenoh_flags
    from vsfleet.wire import Keys

    config = load_config(config_path)
    spec = sim_camera_from_dict(config.sim_camera)
    renderer = Renderer(spec, config.dictionary)
    robots = sorted(m.robot for m in config.markers.values())
    rng = np.random.default_rng(seed)
    with tempfile.TemporaryDirectory() as tmp:
        cal_path, clip = Path(tmp) / "cal.json", Path(tmp) / "clip.avi"
        calibrate_frames([renderer.render(reference_scene(config), 0.0)], config,
                         renderer.camera.intrinsics).save(cal_path)
        writer = write_video(clip, 30.0, (spec.width_px, spec.height_px))
        for k in range(n_frames):
            writer.write(renderer.render(robot_scene(config, spec, random_poses(rng, robots)), k / 30.0))
        writer.release()
        cap = cv2.VideoCapture(str(clip))
        start, decoded = time.perf_counter(), 0
        while cap.read()[0]:
            decoded += 1
        decode_ms = 1000 * (time.perf_counter() - start) / max(decoded, 1)
        cap.release()
        session, endpoint = open_loopback_router()
        received, cond = [0], threading.Condition()

        def on_pose(_sample) -> None:
            with cond:
                received[0] += 1
                cond.notify_all()

        keys = Keys("bench")
        sub = session.declare_subscriber(keys.pose(), on_pose)
        try:
            start = time.perf_counter()
            out = subprocess.run(child_command("tracker", "camera", "--camera", config_path, "--calibration",
                                               str(cal_path), "--source", str(clip), "--no-pace", "--t0",
                                               str(time.time()), "--fleet", "bench", *zenoh_flags(endpoint)),
                                 capture_output=True, text=True, timeout=600, stdin=subprocess.DEVNULL)
            process_wall_s = time.perf_counter() - start
            m = E2E_STATS.findall(out.stderr)
            if out.returncode != 0 or not m:
                raise RuntimeError(f"tracker camera failed ({out.returncode}):\n{out.stderr[-2000:]}")
            frames, wall_s, fps, detect_ms, poses = m[-1]
            with cond:
                cond.wait_for(lambda: received[0] >= int(poses), timeout=5.0)
                got = received[0]
        finally:
            sub.undeclare()
            session.close()
    return {"frames": int(frames), "wall_s": float(wall_s), "fps": float(fps), "detect_ms": float(detect_ms),
            "poses": int(poses), "received": got, "process_wall_s": process_wall_s, "decode_ms": decode_ms}


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--config", default=str(Path(__file__).resolve().parent.parent / "deploy/camera/overhead.toml"))
    p.add_argument("--frames", type=int, default=300)
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--threads", type=int, default=None, help="OpenCV threads (default: OpenCV's choice)")
    p.add_argument("--e2e-frames", type=int, default=300,
                   help="frames of the end-to-end run through `vsfleet tracker camera` (0: skip it)")
    args = p.parse_args()
    if args.threads is not None:
        cv2.setNumThreads(args.threads)
    r = measure(args.config, args.frames, args.seed)
    e = r["calibration_error_mm"]
    load = os.getloadavg()[0]
    print(f"1280x720, 3 x 2 m floor, {r['frames']} frames, {r['poses']} poses, {r['missed']} missed, "
          f"{r['rejected']} rejected")
    print(f"calibration (pinhole, 6 references): reprojection error mean {e['mean']:.2f} mm, max {e['max']:.2f} mm")
    print(f"position error: mean {r['pos_mean_mm']:.2f} mm, p99 {r['pos_p99_mm']:.2f} mm, max {r['pos_max_mm']:.2f} mm")
    print(f"heading error:  mean {r['th_mean_mrad']:.2f} mrad, p99 {r['th_p99_mrad']:.2f} mrad, "
          f"max {r['th_max_mrad']:.2f} mrad ({math.degrees(r['th_max_mrad'] / 1000):.2f} deg)")
    print(f"processing (detect + project) per frame: mean {r['process_ms_mean']:.1f} ms, p95 "
          f"{r['process_ms_p95']:.1f} ms -> {1000 / r['process_ms_mean']:.0f} frames/s "
          f"(OpenCV threads: {cv2.getNumThreads()})")
    print(f"rendering per frame: mean {r['render_ms_mean']:.1f} ms; render + process: "
          f"{1000 / (r['render_ms_mean'] + r['process_ms_mean']):.0f} frames/s")
    print(f"(load average {load:.2f} on {os.cpu_count()} cores while measuring)")
    if args.e2e_frames > 0:
        e = measure_end_to_end(args.config, args.e2e_frames, args.seed + 1)  # OpenCV's default threads
        print(f"end to end through `vsfleet tracker camera --source clip.avi --no-pace` (FFV1 decode + detect + "
              f"publish): {e['frames']} frames in {e['wall_s']:.1f} s -> {e['fps']:.0f} frames/s "
              f"(detection {e['detect_ms']:.1f} ms of it per frame; decoding alone, in this process: "
              f"{e['decode_ms']:.1f} ms per frame); {e['poses']} poses published, "
              f"{e['received']} received; the process ran {e['process_wall_s']:.1f} s with start-up")
        print(f"(load average {os.getloadavg()[0]:.2f} after the end-to-end run)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
