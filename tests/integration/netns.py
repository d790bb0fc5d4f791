"""Hosts as Linux network namespaces: one per host, each with eth0 on a bridge, for fleet tests.

The bridge lives in its own "switch" namespace. The test process joins the lab
network through one more veth pair (an operator laptop on the same switch), so
its zenoh session reaches the router like any host. Needs root and `ip`.
"""

from __future__ import annotations

import os
import secrets
import shutil
import subprocess
from pathlib import Path

from .secured import SecuredFleet

LAB_PORT = 7447


def ip(*args: str, check: bool = True) -> subprocess.CompletedProcess:
    out = subprocess.run(["ip", *args], capture_output=True, text=True)
    if check and out.returncode != 0:
        raise RuntimeError(f"ip {' '.join(args)}: {out.stderr.strip()}")
    return out


def netns_unavailable() -> str | None:
    """Why network namespaces cannot be used here, or None when they can."""
    if os.geteuid() != 0:
        return "needs root to create network namespaces (ip netns add, veth, bridge)"
    if shutil.which("ip") is None:
        return "needs the `ip` tool (iproute2) for network namespaces"
    probe = f"vsfprobe{os.getpid()}{secrets.token_hex(2)}"
    out = ip("netns", "add", probe, check=False)
    if out.returncode != 0:
        return f"`ip netns add` fails here: {out.stderr.strip()}"
    ip("netns", "del", probe, check=False)
    return None


def free_subnet() -> str:
    """A /24 in 198.18.0.0/15 (RFC 2544, benchmarking) that no route here uses: 'a.b.c'."""
    routes = ip("-4", "route", "show", "table", "all").stdout
    for _ in range(100):
        net = f"198.{18 + secrets.randbelow(2)}.{secrets.randbelow(256)}"
        if f"{net}." not in routes and "198.18.0.0/15" not in routes:
            return net
    raise RuntimeError("no free /24 in 198.18.0.0/15 for the test network")


class Lab:
    """A switch (bridge) and hosts, each a namespace with its own address on the switch.

    Names are unique per run (``vsf<pid><hex>-<host>``); ``close()`` deletes every
    namespace, which also deletes every veth pair, including the test's.
    """

    def __init__(self, hosts: list[str]) -> None:
        self.tag = f"vsf{os.getpid() % 100000}{secrets.token_hex(2)}"
        self.subnet = free_subnet()
        self.switch = f"{self.tag}-sw"
        self.namespaces: list[str] = []
        self.port: dict[str, str] = {}      # host -> its port (veth end) in the switch namespace
        self.address: dict[str, str] = {}
        try:
            self._create(hosts)
        except BaseException:
            self.close()
            raise

    def _add_namespace(self, name: str) -> None:
        ip("netns", "add", name)
        self.namespaces.append(name)
        ip("-n", name, "link", "set", "lo", "up")

    def _create(self, hosts: list[str]) -> None:
        self._add_namespace(self.switch)
        ip("-n", self.switch, "link", "add", "br0", "type", "bridge")
        ip("-n", self.switch, "link", "set", "br0", "up")
        for i, host in enumerate(hosts, start=1):
            ns, port = self.ns(host), f"p{i}"
            self._add_namespace(ns)
            tmp = f"{self.tag}e{i}"
            ip("link", "add", tmp, "netns", ns, "type", "veth", "peer", "name", port, "netns", self.switch)
            ip("-n", ns, "link", "set", tmp, "name", "eth0")
            self._plug(port)
            self.address[host] = f"{self.subnet}.{i}"
            ip("-n", ns, "addr", "add", f"{self.address[host]}/24", "dev", "eth0")
            ip("-n", ns, "link", "set", "eth0", "up")
            self.port[host] = port
        # the test process: a veth end in this (the root) namespace, the other on the switch
        self.local_if = f"{self.tag}h"
        ip("link", "add", self.local_if, "type", "veth", "peer", "name", "p0", "netns", self.switch)
        self._plug("p0")
        ip("addr", "add", f"{self.subnet}.254/24", "dev", self.local_if)
        ip("link", "set", self.local_if, "up")

    def _plug(self, port: str) -> None:
        ip("-n", self.switch, "link", "set", port, "master", "br0")
        ip("-n", self.switch, "link", "set", port, "up")

    def ns(self, host: str) -> str:
        return f"{self.tag}-{host}"

    def exec_prefix(self, host: str) -> list[str]:
        return ["ip", "netns", "exec", self.ns(host)]

    def cut(self, host: str) -> None:
        """Unplug the host's cable at the switch (its port goes down)."""
        ip("-n", self.switch, "link", "set", self.port[host], "down")

    def restore(self, host: str) -> None:
        ip("-n", self.switch, "link", "set", self.port[host], "up")

    def close(self) -> None:
        for ns in reversed(self.namespaces):
            ip("netns", "del", ns, check=False)
        self.namespaces.clear()
        if getattr(self, "local_if", None):
            ip("link", "del", self.local_if, check=False)  # normally gone with the switch


class NetnsFleet(SecuredFleet):
    """The deployed fleet with every process on its own host: router, sim+tracker, one per agent.

    Children run under ``ip netns exec``; the router listens on its lab address, port 7447, and
    everyone dials it, logging in with usrpwd under the deploy access control.
    """

    HOSTS = {"router": "router", "sim": "camera", "tracker": "camera"}

    def __init__(self, scenario_path: str | Path, log_dir: Path, lab: Lab) -> None:
        self.lab = lab
        super().__init__(scenario_path, log_dir, auth="usrpwd")

    @staticmethod
    def host_of(name: str) -> str:
        """router -> router, sim and tracker -> camera, agent-rN -> robot-rN."""
        return NetnsFleet.HOSTS.get(name, name.replace("agent-", "robot-"))

    def router_host(self) -> str:
        return self.lab.address["router"]

    def router_listen_port(self) -> int:
        return LAB_PORT

    def namespace_of(self, name: str) -> list[str]:
        return self.lab.exec_prefix(self.host_of(name))
