"""The wheel installs everything under the vsfleet namespace: no generic top-level packages."""

import subprocess
import sys
import sysconfig
import zipfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent.parent


def test_the_wheel_has_only_the_vsfleet_package_and_its_command_works_without_the_repository(tmp_path):
    out = subprocess.run([sys.executable, "-m", "pip", "wheel", str(ROOT), "--no-deps", "--no-build-isolation",
                          "-w", str(tmp_path / "dist"), "-q"], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    wheel = next((tmp_path / "dist").glob("vsfleet-*.whl"))
    with zipfile.ZipFile(wheel) as z:
        names = z.namelist()
        z.extractall(tmp_path / "site")
        entry = next(n for n in names if n.endswith("entry_points.txt"))
        entry_points = z.read(entry).decode()
    tops = {n.split("/")[0] for n in names if not n.split("/")[0].endswith((".dist-info", ".data"))}
    assert tops == {"vsfleet"}, tops
    assert {"vsfleet/agent/main.py", "vsfleet/fleetctl/cli.py", "vsfleet/simfleet/main.py",
            "vsfleet/tracker/sim.py"} <= set(names)
    assert "vsfleet = vsfleet.fleetctl.cli:main" in entry_points
    # the installed wheel alone (and the dependencies), not the repository nor its editable install:
    # -S skips site-packages' .pth files, so the editable finder that maps this checkout is not loaded
    deps = sysconfig.get_paths()["purelib"]
    probe = ("import sys; sys.path[:0] = [{site!r}, {deps!r}]\n"
             "try:\n    import agent\nexcept ModuleNotFoundError:\n    print('no top-level agent')\n"
             "else:\n    print('agent found at', agent.__file__)\n"
             "import vsfleet.agent.main, vsfleet.fleetctl.cli as cli\n"
             "print('from', vsfleet.agent.main.__file__)\n"
             "sys.argv = ['vsfleet', '--help']\ncli.main()\n").format(site=str(tmp_path / "site"), deps=deps)
    run = subprocess.run([sys.executable, "-S", "-c", probe], capture_output=True, text=True, cwd=tmp_path,
                         timeout=120)
    assert "no top-level agent" in run.stdout, run.stdout + run.stderr
    assert f"from {tmp_path / 'site'}" in run.stdout, run.stdout
    text = run.stdout + run.stderr
    assert "usage: vsfleet" in text and "one agent per robot" in text and "Traceback" not in text, text
