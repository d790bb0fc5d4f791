"""A LoopbackFleet deployed as on real hosts: `vsfleet router --config` with access control.

Configs come from `vsfleet deploy config` (fleetctl.deploy), installed into one
directory; every child logs in with its own identity, the observer as operator.
"""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import zenoh

from vsfleet.fleetctl.deploy import write_deploy
from vsfleet.fleetctl.run import child_command

from .conftest import LoopbackFleet, wait_port


def install_deploy(out: Path, fleet: str, robots, router_endpoint: str, auth: str) -> Path:
    """Generate the deploy files and install every host's share into one etc directory."""
    etc = out / "etc"
    write_deploy(out / "generated", fleet, robots, router_endpoint, auth, conf_dir=str(etc),
                 listen=[router_endpoint], sim=True)  # simulated robots: the sim login
    etc.mkdir(parents=True, exist_ok=True)
    for host in (out / "generated").iterdir():
        if host.name != "pki":
            for f in host.iterdir():
                shutil.copy2(f, etc / f.name)
    return etc


def identity_of(name: str) -> str:
    """The login a child process uses: agent-rN logs in as rN, sim as sim, tracker as tracker."""
    return name.removeprefix("agent-")


class SecuredFleet(LoopbackFleet):
    """The fleet with the deployed router (`vsfleet router --config`), auth usrpwd or mtls."""

    def __init__(self, scenario_path: str | Path, log_dir: Path, auth: str = "usrpwd") -> None:
        self.auth = auth
        self.etc: Path | None = None
        self.log_dir = log_dir
        self.procs: dict[str, subprocess.Popen] = {}
        try:
            super().__init__(scenario_path, log_dir, router_process=True)
        except BaseException:
            for p in self.procs.values():
                p.kill()
                p.wait()
            raise

    # ---------------------------------------------------------------- where the router is
    def router_host(self) -> str:
        return "127.0.0.1"

    def router_listen_port(self) -> int:
        return self.router_port

    def router_endpoint(self) -> str:
        proto = "tls" if self.auth == "mtls" else "tcp"
        return f"{proto}/{self.router_host()}:{self.router_listen_port()}"

    def namespace_of(self, name: str) -> list[str]:
        """Command prefix that puts a child on its host; none on loopback."""
        return []

    # ---------------------------------------------------------------- processes
    def client_config(self, identity: str) -> Path:
        return self.etc / f"{identity}.json5"

    def start(self, name: str, *args: str) -> subprocess.Popen:
        conf = self.etc / "router.json5" if name == "router" else self.client_config(identity_of(name))
        cmd = [*self.namespace_of(name), *child_command(*args, "--config", str(conf))]
        with (self.log_dir / f"{name}.log").open("ab") as out:
            p = subprocess.Popen(cmd, stdout=out, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                                 start_new_session=True)
        self.procs[name] = p
        return p

    def start_router(self) -> subprocess.Popen:
        """Start (or restart) `vsfleet router --config router.json5`; waits until it listens."""
        if self.etc is None:
            robots = [r.robot for r in self.scenario.robots]
            self.etc = install_deploy(self.log_dir / "deploy", self.scenario.fleet, robots,
                                      self.router_endpoint(), self.auth)
        self.endpoint = self.router_endpoint()
        p = self.start("router", "router", "--config", str(self.etc / "router.json5"))
        wait_port(self.router_listen_port(), 20.0, host=self.router_host())
        return p

    def open_observer(self) -> zenoh.Session:
        """The observer logs in as operator (it may subscribe to all, put mission and faults)."""
        return self.open_as("operator")

    def open_as(self, identity: str) -> zenoh.Session:
        """A session of the test process that logs in as ``identity`` (waits for the router 10 s)."""
        conf = zenoh.Config.from_file(str(self.client_config(identity)))
        conf.insert_json5("connect/timeout_ms", "10000")
        conf.insert_json5("connect/exit_on_failure", "true")
        return zenoh.open(conf)
