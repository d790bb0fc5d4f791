"""The ``vsfleet`` console script: one subcommand per program; each ``main`` is importable.

Errors reach the user as one line ``vsfleet COMMAND: ...``; an unexpected exception's
traceback is shown only with --verbose (before or after the command).
"""

from __future__ import annotations

import importlib
import os
import sys
import threading
import traceback

# Every program works on arrays of a few hundred numbers at most, where OpenBLAS's thread pool only costs: it spins
# about 50 ms of CPU in each process that imports numpy, and again after each BLAS call (this host, 2026-12-04: an
# idle process 51 ms over its first second, 3 ms with one thread). Set before any program imports numpy; an
# environment that says otherwise is left alone. (zglue/forks.py sets the same for the fork server.)
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

# command -> (module, what it is). The one tool module that names programs: `vsfleet agent` loads the
# agent by name and runs its main as the agent's own process (tests/test_purity.py, docs/architecture.md)
COMMANDS = {
    "agent": ("vsfleet.agent.main", "one agent per robot"),
    "sim": ("vsfleet.simfleet.main", "the simulated fleet"),
    "tracker sim": ("vsfleet.tracker.sim", "the simulated tracker (VGPS)"),
    "tracker camera": ("vsfleet.tracker.camera", "ArUco markers from an overhead camera -> poses"),
    "tracker calibrate": ("vsfleet.tracker.calibrate", "floor calibration from reference markers"),
    "render": ("vsfleet.tracker.render", "synthetic overhead camera frames of the simulated fleet"),
    "run": ("vsfleet.fleetctl.run", "the localhost multi-process fleet from a scenario"),
    "router": ("vsfleet.fleetctl.router", "a zenoh router (router-mode zenoh-python session)"),
    "deploy config": ("vsfleet.fleetctl.deploy", "zenoh configs with logins and access control for real hosts"),
    "mission set": ("vsfleet.fleetctl.mission_cmd", "publish a mission file"),
    "record": ("vsfleet.fleetctl.record", "record a fleet's key space into an MCAP file"),
    "replay": ("vsfleet.fleetctl.replay", "publish a recording back into a key space"),
    "plot": ("vsfleet.fleetctl.plot", "the paper's figures (PNG) from a recording"),
    "monitor": ("vsfleet.fleetctl.monitor", "live terminal view of a running fleet"),
    "foxglove": ("vsfleet.fleetctl.foxglove_live", "live Foxglove WebSocket server on a fleet's key space"),
    "fuzz": ("vsfleet.fleetctl.fuzz", "throw invalid messages at every key the fleet subscribes to"),
    "bridge ros2": ("vsfleet.fleetctl.bridge_ros2", "one robot's commands -> geometry_msgs/Twist over rmw_zenoh"),
    "bridge ros2-poses": ("vsfleet.fleetctl.bridge_ros2_poses", "mocap PoseStamped/Odometry over rmw_zenoh -> frames"),
}

_WIDTH = max(map(len, COMMANDS))
USAGE = ("usage: vsfleet [--version] [--verbose] COMMAND [ARGS...]\n\ncommands:\n" + "\n".join(
    f"  {name:<{_WIDTH}}  {doc}" for name, (_, doc) in COMMANDS.items())
    + "\n\nvsfleet COMMAND --help describes a command's flags.")


def version() -> str:
    """The installed package's version (pyproject.toml), or 'unknown' when run from a bare checkout."""
    import importlib.metadata   # here: 12-27 ms at import, and only --version needs it (issue 29, start-up)
    try:
        return importlib.metadata.version("vsfleet")
    except importlib.metadata.PackageNotFoundError:
        return "unknown (not installed)"


def _say(name: str, message: str) -> None:
    print(f"vsfleet {name}: {message}", file=sys.stderr, flush=True)


def _one_line(exc: BaseException) -> str:
    text = " ".join(str(exc).split())
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


def run_command(name: str, module_name: str, args: list[str], verbose: bool) -> int:
    """Run one program's main; every error becomes one line (and exit code 2, or 1 if unexpected)."""
    from vsfleet.zglue.zconf import SessionError, StoppedWaiting, ZenohConfigError

    def thread_hook(hook_args) -> None:  # a crashed worker thread: one line, the traceback only if verbose
        if verbose:
            traceback.print_exception(hook_args.exc_type, hook_args.exc_value, hook_args.exc_traceback)
        else:
            _say(name, f"thread {hook_args.thread.name if hook_args.thread else '?'} failed: "
                       f"{_one_line(hook_args.exc_value)} (--verbose shows the traceback)")

    previous_hook, threading.excepthook = threading.excepthook, thread_hook
    try:
        try:
            module = importlib.import_module(module_name)
        except ModuleNotFoundError as exc:
            if (exc.name or "").split(".")[0] != "cv2":
                raise
            _say(name, "needs OpenCV, which is not installed: install vsfleet[camera] (pip install '.[camera]')")
            return 2
        return int(module.main(args) or 0)
    except (SessionError, ZenohConfigError) as exc:
        _say(name, str(exc))
        return 2
    except StoppedWaiting as exc:
        _say(name, str(exc))
        if exc.open_pending:  # a zenoh.open still blocks in the background: exit without waiting on it
            # (no logging.shutdown: it takes every handler's lock, and each record was flushed as written)
            for stream in (sys.stdout, sys.stderr):
                try:
                    stream.flush()
                except (OSError, ValueError):
                    pass
            os._exit(0)
        return 0
    except SystemExit as exc:  # argparse (int codes, its message already printed) or SystemExit("text")
        if exc.code is None or isinstance(exc.code, int):
            return exc.code or 0
        _say(name, str(exc.code))
        return 2
    except KeyboardInterrupt:
        _say(name, "interrupted")
        return 130
    except BrokenPipeError:  # e.g. `vsfleet ... | head`: the reader left
        return 1
    except Exception as exc:  # noqa: BLE001 - the last line of defence: no traceback unless asked
        if verbose:
            traceback.print_exc()
        _say(name, f"unexpected error: {_one_line(exc)}"
                   + ("" if verbose else f" (run `vsfleet {name} ... --verbose` for the traceback)"))
        return 1
    finally:
        threading.excepthook = previous_hook


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    verbose = False
    while argv[:1] in (["--verbose"], ["-v"]):
        verbose = True
        argv = argv[1:]
    if argv[:1] in (["--version"], ["-V"]):
        print(f"vsfleet {version()}")
        return 0
    for n_words in (2, 1):
        name = " ".join(argv[:n_words])
        if len(argv) >= n_words and name in COMMANDS:
            args = argv[n_words:]
            if verbose and "--verbose" not in args and "-v" not in args:
                args = [*args, "--verbose"]  # every program takes it (zglue.program.common_flags)
            verbose = verbose or "--verbose" in args or "-v" in args
            return run_command(name, COMMANDS[name][0], args, verbose)
    if argv and argv[0] not in ("-h", "--help"):
        print(f"vsfleet: unknown command {' '.join(argv[:2])!r}\n", file=sys.stderr)
    print(USAGE, file=sys.stderr)
    return 0 if argv[:1] in (["-h"], ["--help"]) else 2


if __name__ == "__main__":
    raise SystemExit(main())
