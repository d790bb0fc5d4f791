"""The ``vsfleet`` console script: one subcommand per program; each ``main`` is importable."""

from __future__ import annotations

import importlib
import sys

COMMANDS = {
    "agent": ("agent.main", "one agent per robot"),
    "sim": ("simfleet.main", "the simulated fleet"),
    "tracker sim": ("tracker.sim", "the simulated tracker (VGPS)"),
    "tracker camera": ("tracker.camera", "ArUco markers from an overhead camera -> poses"),
    "tracker calibrate": ("tracker.calibrate", "floor calibration from reference markers"),
    "render": ("tracker.render", "synthetic overhead camera frames of the simulated fleet"),
    "run": ("fleetctl.run", "the localhost multi-process fleet from a scenario"),
    "router": ("fleetctl.router", "a zenoh router (router-mode zenoh-python session)"),
    "deploy config": ("fleetctl.deploy", "zenoh configs with logins and access control for real hosts"),
    "mission set": ("fleetctl.mission_cmd", "publish a mission file"),
    "record": ("fleetctl.record", "record a fleet's key space into an MCAP file"),
    "replay": ("fleetctl.replay", "publish a recording back into a key space"),
    "plot": ("fleetctl.plot", "the paper's figures (PNG) from a recording"),
    "monitor": ("fleetctl.monitor", "live terminal view of a running fleet"),
    "fuzz": ("fleetctl.fuzz", "throw invalid messages at every key the fleet subscribes to"),
    "bridge ros2": ("fleetctl.bridge_ros2", "one robot's commands -> geometry_msgs/Twist over rmw_zenoh"),
    "bridge ros2-poses": ("fleetctl.bridge_ros2_poses", "mocap PoseStamped/Odometry over rmw_zenoh -> frames"),
}

USAGE = "usage: vsfleet COMMAND [ARGS...]\n\ncommands:\n" + "\n".join(
    f"  {name:<14} {doc}" for name, (_, doc) in COMMANDS.items())


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    for n_words in (2, 1):
        name = " ".join(argv[:n_words])
        if len(argv) >= n_words and name in COMMANDS:
            try:
                module = importlib.import_module(COMMANDS[name][0])
            except ModuleNotFoundError as exc:
                if (exc.name or "").split(".")[0] != "cv2":
                    raise
                print(f"vsfleet {name}: needs OpenCV, which is not installed: install vsfleet[camera] "
                      "(pip install '.[camera]')", file=sys.stderr)
                return 2
            return int(module.main(argv[n_words:]) or 0)
    print(USAGE, file=sys.stderr)
    return 0 if argv[:1] in (["-h"], ["--help"]) else 2


if __name__ == "__main__":
    raise SystemExit(main())
