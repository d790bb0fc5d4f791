"""The wheel, installed as a user installs it, outside the repository: everything under the vsfleet
namespace, every command that ``vsfleet --help`` lists answers ``--help``, and a fleet of the
installed commands (router, sim, tracker, three agents) reaches the goal.

The wheel is built from the checkout (``pip wheel --no-build-isolation --no-deps``, the compiled core
included) and installed with ``pip --python`` into a fresh virtual environment in a temporary
folder, without pip of its own. Its dependencies come from this environment's site-packages by a
``.pth`` line after its own: that folder is then a plain path entry, so its ``.pth`` files (the
editable install that maps this checkout) are not run. Every command runs from a temporary folder,
with neither the repository nor its editable install on its path, so a module name that imports
only from the checkout's root (``fleetctl.bridge_ros2``) fails here.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
import time
import zipfile
from pathlib import Path

import pytest
import zenoh

from .conftest import E2E, LoopbackFleet, at_goal, closing, start_fleet

ROOT = Path(__file__).resolve().parent.parent.parent


@pytest.fixture(scope="module")
def installed(tmp_path_factory):
    """(wheel, the venv's bin folder, a working folder outside the repository, a clean environment)."""
    base = tmp_path_factory.mktemp("installed")
    t0 = time.perf_counter()
    out = subprocess.run([sys.executable, "-m", "pip", "wheel", str(ROOT), "--no-deps", "--no-build-isolation",
                          "-w", str(base / "dist"), "-q"], capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr
    wheel = next((base / "dist").glob("vsfleet-*.whl"))
    t1 = time.perf_counter()
    venv = base / "venv"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)], check=True, timeout=120)
    py = venv / "bin" / "python"
    site = Path(subprocess.run([py, "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                               capture_output=True, text=True, check=True).stdout.strip())
    out = subprocess.run([sys.executable, "-m", "pip", "--python", str(py), "install", "--no-deps", "--no-index",
                          "-q", str(wheel)], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    # only then the dependencies (pip would take this environment's editable vsfleet for the installed one)
    (site / "zz_vsfleet_dependencies.pth").write_text(str(Path(zenoh.__file__).resolve().parent.parent) + "\n")
    work = base / "work"
    work.mkdir()
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME", "VIRTUAL_ENV")}
    env["PATH"] = f"{venv / 'bin'}{os.pathsep}{env.get('PATH', '')}"
    print(f"wheel built in {t1 - t0:.1f} s, installed in {time.perf_counter() - t1:.1f} s")
    return wheel, venv / "bin", work, env


def test_the_wheel_has_only_the_vsfleet_package_and_installs_outside_the_repository(installed):
    wheel, bin_dir, work, env = installed
    with zipfile.ZipFile(wheel) as z:
        names = z.namelist()
        entry_points = z.read(next(n for n in names if n.endswith("entry_points.txt"))).decode()
    tops = {n.split("/")[0] for n in names if not n.split("/")[0].endswith((".dist-info", ".data"))}
    assert tops == {"vsfleet"}, tops
    assert {"vsfleet/agent/main.py", "vsfleet/fleetctl/cli.py", "vsfleet/simfleet/main.py", "vsfleet/tracker/sim.py",
            "vsfleet/zglue/zconf.py", "vsfleet/zglue/program.py"} <= set(names)
    assert any(re.fullmatch(r"vsfleet/_core\..*\.so", n) for n in names), "the compiled core is not in the wheel"
    assert "vsfleet = vsfleet.fleetctl.cli:main" in entry_points
    probe = ("import sys, vsfleet, vsfleet._core, vsfleet.agent.main, vsfleet.zglue.zconf\n"
             "for name in ('agent', 'fleetctl', 'zglue', 'tracker', 'simfleet'):\n"
             "    try:\n        __import__(name)\n    except ModuleNotFoundError:\n        pass\n"
             "    else:\n        print('top-level', name, 'imports')\n"
             "print('\\n'.join(m.__file__ for m in (vsfleet, vsfleet._core, vsfleet.agent.main)))\n")
    run = subprocess.run([bin_dir / "python", "-c", probe], capture_output=True, text=True, cwd=work, env=env,
                         timeout=60)
    assert run.returncode == 0, run.stderr
    assert "top-level" not in run.stdout, run.stdout
    venv = bin_dir.parent.resolve()
    for line in run.stdout.split():
        assert Path(line).resolve().is_relative_to(venv), f"{line} is not the installed copy ({venv})"


def listed_commands(help_text: str) -> list[str]:
    """The commands ``vsfleet --help`` lists: each line under 'commands:' is NAME, two spaces, its doc."""
    block = help_text.split("commands:\n", 1)[1].split("\n\n", 1)[0]
    return [re.split(r"\s{2,}", line.strip())[0] for line in block.splitlines() if line.strip()]


def test_every_command_vsfleet_lists_answers_help_when_installed(installed):
    _, bin_dir, work, env = installed
    out = subprocess.run([bin_dir / "vsfleet", "--help"], capture_output=True, text=True, cwd=work, env=env,
                         timeout=60)
    assert out.returncode == 0, out.stderr
    commands = listed_commands(out.stdout + out.stderr)
    assert len(commands) >= 18 and {"agent", "bridge ros2", "bridge ros2-poses", "tracker sim"} <= set(commands)
    failed = {}
    t0 = time.perf_counter()
    for name in commands:
        run = subprocess.run([bin_dir / "vsfleet", *name.split(), "--help"], capture_output=True, text=True,
                             cwd=work, env=env, timeout=120)
        if run.returncode != 0 or "usage:" not in run.stdout:
            failed[name] = (run.returncode, (run.stdout + run.stderr)[-600:])
    print(f"{len(commands)} commands answered --help in {time.perf_counter() - t0:.1f} s")
    assert not failed, failed


class InstalledFleet(LoopbackFleet):
    """The e2e-triangle fleet of the installed `vsfleet` commands, started from a folder outside the repository."""

    def __init__(self, installed, log_dir: Path) -> None:
        _, self.bin_dir, self.work, self.env = installed
        super().__init__(E2E, log_dir, router_process=True)

    def start(self, name: str, *args: str) -> subprocess.Popen:
        flags = [] if name == "router" else self.flags
        with (self.log_dir / f"{name}.log").open("ab") as out:
            p = subprocess.Popen([str(self.bin_dir / "vsfleet"), *args, *flags], stdout=out, stderr=subprocess.STDOUT,
                                 stdin=subprocess.DEVNULL, start_new_session=True, cwd=self.work, env=self.env)
        self.procs[name] = p
        return p


def test_a_fleet_of_the_installed_commands_reaches_the_goal(installed, tmp_path, request):
    fleet = InstalledFleet(installed, tmp_path)
    try:
        t0 = time.perf_counter()
        start_fleet(fleet)
        fleet.observed.wait_for(at_goal(fleet, tol_m=0.02), timeout_s=2 * fleet.scenario.duration_s)
        print(f"router, sim, tracker and three agents installed: at the goal {time.perf_counter() - t0:.1f} s "
              "after starting")
        assert {name: p.poll() for name, p in fleet.procs.items()} == dict.fromkeys(fleet.procs), "a child exited"
    finally:
        closing(fleet, request)
