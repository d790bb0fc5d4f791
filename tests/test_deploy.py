"""deploy/: the generated zenoh configs, their access-control matrix, the examples and systemd units."""

from __future__ import annotations

import json
import os
import shlex
import shutil
import stat
import subprocess
import sys
from configparser import ConfigParser
from pathlib import Path

import pytest
import zenoh

from vsfleet.fleetctl import deploy
from vsfleet.fleetctl.cli import COMMANDS
from vsfleet.zglue.scenario_file import load_scenario
from vsfleet.wire import Keys

ROOT = Path(__file__).parent.parent
DEPLOY = ROOT / "deploy"
ROBOTS = ("r1", "r2", "r3")


def read_json5(path: Path) -> dict:
    """Our generated files: JSON under // comment lines."""
    return json.loads("".join(line for line in path.read_text().splitlines(keepends=True)
                              if not line.lstrip().startswith("//")))


def allowed(acl: dict, user: str, flow: str, message: str, key: str) -> bool:
    """Evaluate the ACL as the router does for a usrpwd login: deny beats allow beats default."""
    subjects = {s["id"] for s in acl["subjects"] if user in s.get("usernames", [user])}
    rules = {r["id"]: r for r in acl["rules"]}
    verdicts = set()
    for policy in acl["policies"]:
        if subjects & set(policy["subjects"]):
            for rid in policy["rules"]:
                r = rules[rid]
                if (flow in r.get("flows", ["ingress", "egress"]) and message in r["messages"]
                        and any(zenoh.KeyExpr(k).includes(zenoh.KeyExpr(key)) for k in r["key_exprs"])):
                    verdicts.add(r["permission"])
    if "deny" in verdicts:
        return False
    return "allow" in verdicts or acl["default_permission"] == "allow"


@pytest.fixture(scope="module")
def acl():
    return deploy.access_control("lab", ROBOTS, sim=True)


LOGINS = deploy.identities(ROBOTS, sim=True)


def test_only_the_right_identity_may_put_each_key(acl):
    k = Keys("lab")
    may_put = {
        k.pose("r1"): {"tracker"}, k.pose("r3"): {"tracker"},
        k.truth("r2"): {"sim"},
        k.mission: {"operator"}, k.fault("r1"): {"operator"},
        k.cmd("r1"): {"r1"}, k.state("r1"): {"r1"}, k.cmd("r2"): {"r2"}, k.state("r3"): {"r3"},
        k.event("r1"): {"r1"}, k.event("r2"): {"r2"}, k.event("*"): set(), f"{k.prefix}/event": set(),
        k.cmd("*"): set(), k.everything: set(), "vs/other/cmd/r1": set(), "elsewhere/x": set(),
    }
    for key, who in may_put.items():
        got = {u for u in LOGINS if allowed(acl, u, "ingress", "put", key)}
        assert got == who, key
    for u in LOGINS:
        assert not allowed(acl, u, "ingress", "delete", k.cmd("r1"))
        assert not allowed(acl, "intruder", "ingress", "declare_subscriber", k.everything)


def test_tokens_and_queryables_belong_to_their_owner(acl):
    k = Keys("lab")
    tokens = {k.alive("agent", "r1"): {"r1"}, k.alive("agent", "r2"): {"r2"},
              k.alive("tracker", "cam1"): {"tracker"}, k.alive("sim", "simfleet"): {"sim"},
              k.alive("agent", "r9"): set()}
    for key, who in tokens.items():
        assert {u for u in LOGINS if allowed(acl, u, "ingress", "liveliness_token", key)} == who

    def answer(key):
        return {u for u in LOGINS if allowed(acl, u, "ingress", "declare_queryable", key)
                and allowed(acl, u, "ingress", "reply", key)}

    # the operator's mission answers (vsfleet run) are the operator's alone; each agent answers
    # only under its own key, so no robot's login can answer for another
    assert answer(k.mission) == {"operator"}
    assert answer(k.peer_mission("r1")) == {"r1"} and answer(k.peer_health("r1")) == {"r1"}
    assert answer(k.peer_mission("r2")) == {"r2"} and answer(k.peer_health("r3")) == {"r3"}
    for key in (k.peer_mission(), k.peer_health(), f"{k.peer()}/**", f"{k.prefix}/health"):
        assert answer(key) == set(), key


def test_without_sim_there_is_no_sim_login_and_nobody_may_put_truth():
    assert deploy.identities(ROBOTS) == ("tracker", "operator", *ROBOTS)
    acl = deploy.access_control("lab", ROBOTS)
    assert all(s["id"] != "sim" for s in acl["subjects"])
    assert "sim" not in acl["subjects"][0]["usernames"]
    k = Keys("lab")
    for u in (*LOGINS, "sim"):
        assert not allowed(acl, u, "ingress", "put", k.truth("r1")), u
        assert not allowed(acl, u, "ingress", "liveliness_token", k.alive("sim", "simfleet")), u


def test_everyone_logged_in_may_subscribe_query_and_be_delivered_to(acl):
    k = Keys("lab")
    for u in LOGINS:
        for msg in ("declare_subscriber", "declare_liveliness_subscriber", "liveliness_query", "query"):
            assert allowed(acl, u, "ingress", msg, k.pose("r1")), (u, msg)
        for msg in ("put", "declare_subscriber", "declare_queryable", "liveliness_token", "query", "reply"):
            assert allowed(acl, u, "egress", msg, k.state("r2")), (u, msg)
    assert allowed(acl, "operator", "ingress", "query", "@/1234/router")  # admin space: operator only
    assert not allowed(acl, "r1", "ingress", "query", "@/1234/router")


def test_mtls_subjects_match_certificate_common_names():
    acl = deploy.access_control("lab", ROBOTS, auth="mtls")
    assert {"id": "r1", "cert_common_names": ["r1"]} in acl["subjects"]
    assert all("usernames" not in s for s in acl["subjects"])


@pytest.mark.parametrize("robots, message", [
    (("r1", "tracker"), "clashes with the 'tracker' identity"),
    (("r1", "sim"), "clashes with the 'sim' identity"),
    (("r1", "router"), "robot id 'router' is reserved"),
    (("pki", "r1"), "robot id 'pki' is reserved"),
    (("r1", "everyone"), "robot id 'everyone' is reserved"),
    (("agent",), "robot id 'agent' is reserved"),
    (("r1", "r1"), "distinct"),
    ((), "at least one"),
    (("r/1",), "robot id"),
])
def test_bad_robot_lists_are_refused_with_a_clear_message(robots, message):
    with pytest.raises(deploy.DeployError, match=message):
        deploy.identities(robots)


def test_bad_inputs_are_refused_with_a_clear_message(tmp_path):
    with pytest.raises(deploy.DeployError, match="auth must be one of"):
        deploy.access_control("lab", ROBOTS, auth="none")
    with pytest.raises(deploy.DeployError, match="fleet"):
        deploy.access_control("la b", ROBOTS)
    with pytest.raises(deploy.DeployError, match="must start with tls/"):
        deploy.write_deploy(tmp_path, "lab", ROBOTS, "tcp/10.0.0.1:7447", auth="mtls")
    with pytest.raises(deploy.DeployError, match="without ':'"):
        deploy.write_deploy(tmp_path, "lab", ROBOTS, "tcp/10.0.0.1:7447", passwords={"r1": "a:b"})
    with pytest.raises(deploy.DeployError, match="listen endpoint"):
        deploy.router_config("lab", ROBOTS, [], dictionary_file="/x")


def test_write_deploy_gives_every_host_its_login_and_the_router_a_matching_dictionary(tmp_path):
    paths = deploy.write_deploy(tmp_path, "lab", ROBOTS, "tcp/10.0.0.1:7447", fleet_file=DEPLOY / "fleet.toml",
                                sim=True)
    assert set(paths) == {"tracker", "sim", "operator", *ROBOTS}
    dictionary = dict(line.split(":", 1) for line in (tmp_path / "router" / "passwords").read_text().split())
    assert set(dictionary) == set(paths) and len(set(dictionary.values())) == len(paths)
    for ident, path in paths.items():
        conf = read_json5(path)
        assert conf["mode"] == "client" and conf["connect"]["endpoints"] == ["tcp/10.0.0.1:7447"]
        assert conf["transport"]["auth"]["usrpwd"] == {"user": ident, "password": dictionary[ident]}
        assert stat.S_IMODE(path.stat().st_mode) == 0o600
        zenoh.Config.from_file(str(path))  # zenoh accepts it
    assert stat.S_IMODE((tmp_path / "router" / "passwords").stat().st_mode) == 0o600
    router = read_json5(tmp_path / "router" / "router.json5")
    assert router["transport"]["auth"]["usrpwd"]["dictionary_file"] == "/etc/vsfleet/passwords"
    assert router["listen"]["endpoints"] == ["tcp/0.0.0.0:7447"]
    assert (tmp_path / "sim" / "fleet.toml").exists() and (tmp_path / "operator" / "fleet.toml").exists()
    assert "VSFLEET_FLEET=lab" in (tmp_path / "r1" / "vsfleet.env").read_text()
    # services wait for the router; the operator's one-shot commands give up
    assert read_json5(paths["r1"])["connect"]["timeout_ms"] == -1
    assert read_json5(paths["operator"])["connect"]["exit_on_failure"] is True


def test_the_sim_login_is_made_only_when_asked_for(tmp_path):
    paths = deploy.write_deploy(tmp_path, "lab", ROBOTS, "tcp/10.0.0.1:7447")
    assert set(paths) == {"tracker", "operator", *ROBOTS} and not (tmp_path / "sim").exists()
    assert not any(line.startswith("sim:") for line in (tmp_path / "router" / "passwords").read_text().split())
    router = read_json5(tmp_path / "router" / "router.json5")
    assert router["access_control"] == deploy.access_control("lab", ROBOTS)


SECRETS = {"usrpwd": ["router/passwords", "router/router.json5", "r1/r1.json5", "operator/operator.json5"],
           "mtls": ["pki/ca.key", "pki/router.key", "pki/r1.key", "router/router.key", "r1/r1.key",
                    "operator/operator.key", "router/router.json5", "r1/r1.json5"]}


@pytest.mark.parametrize("auth", ["usrpwd", pytest.param("mtls", marks=pytest.mark.integration)])  # openssl
def test_secret_files_are_created_private_not_made_private_afterwards(tmp_path, monkeypatch, auth):
    """With chmod out of action, only the mode a file is created with counts: it must already be 0600."""
    if auth == "mtls" and shutil.which("openssl") is None:
        pytest.skip("needs the openssl command-line tool")
    old = os.umask(0o022)
    try:
        monkeypatch.setattr(os, "chmod", lambda *args, **kwargs: None)
        endpoint = "tls/10.0.0.1:7447" if auth == "mtls" else "tcp/10.0.0.1:7447"
        deploy.write_deploy(tmp_path, "lab", ROBOTS, endpoint, auth=auth)
    finally:
        os.umask(old)
    for rel in SECRETS[auth]:
        mode = stat.S_IMODE((tmp_path / rel).stat().st_mode)
        assert mode & 0o077 == 0, f"{rel} was created mode {oct(mode)}"
    monkeypatch.undo()
    # written again over files that are readable by others: private again
    (tmp_path / "r1" / "r1.json5").chmod(0o644)
    deploy.write_deploy(tmp_path, "lab", ROBOTS, endpoint, auth=auth)
    assert stat.S_IMODE((tmp_path / "r1" / "r1.json5").stat().st_mode) == 0o600


@pytest.mark.integration  # starts a child process (tests/conftest.py)
@pytest.mark.skipif(shutil.which("openssl") is None, reason="needs the openssl command-line tool")
def test_mtls_deploy_makes_certificates_with_the_identities_as_common_names(tmp_path):
    paths = deploy.write_deploy(tmp_path, "lab", ROBOTS, "tls/10.0.0.1:7447", auth="mtls")
    subject = subprocess.run(["openssl", "x509", "-noout", "-subject", "-ext", "subjectAltName",
                              "-in", str(tmp_path / "router" / "router.pem")], capture_output=True, text=True)
    assert "CN = router" in subject.stdout and "IP Address:10.0.0.1" in subject.stdout
    for ident, path in paths.items():
        tls = read_json5(path)["transport"]["link"]["tls"]
        assert tls["enable_mtls"] is True and tls["connect_certificate"] == f"/etc/vsfleet/{ident}.pem"
        cn = subprocess.run(["openssl", "x509", "-noout", "-subject", "-in", str(path.parent / f"{ident}.pem")],
                            capture_output=True, text=True).stdout
        assert f"CN = {ident}" in cn
        verify = subprocess.run(["openssl", "verify", "-CAfile", str(path.parent / "ca.pem"),
                                 str(path.parent / f"{ident}.pem")], capture_output=True, text=True)
        assert verify.returncode == 0, verify.stderr
    assert not (tmp_path / "r1" / "ca.key").exists()  # the CA key stays with the admin
    # the router's certificate serves TLS only, every login's certificate is a TLS client only

    def usage(pem):
        return subprocess.run(["openssl", "x509", "-noout", "-ext", "extendedKeyUsage", "-in", str(pem)],
                              capture_output=True, text=True).stdout.splitlines()[-1].strip()

    assert usage(tmp_path / "router" / "router.pem") == "TLS Web Server Authentication"
    for ident, path in paths.items():
        assert usage(path.parent / f"{ident}.pem") == "TLS Web Client Authentication", ident


def test_the_checked_in_examples_are_what_the_generator_writes():
    scenario = load_scenario(DEPLOY / "fleet.toml")
    robots = [r.robot for r in scenario.robots]
    router = read_json5(DEPLOY / "router.json5")
    assert router == deploy.router_config(scenario.fleet, robots, ["tcp/0.0.0.0:7447"],
                                          dictionary_file="/etc/vsfleet/passwords")
    for name, ident in (("robot-client", "r1"), ("tracker-client", "tracker"), ("operator-client", "operator")):
        assert read_json5(DEPLOY / f"{name}.json5") == deploy.client_config(
            ident, ["tcp/ROUTER_HOST:7447"], password="CHANGE_ME"), name
    for f in DEPLOY.glob("*.json5"):
        zenoh.Config.from_file(str(f))


@pytest.mark.integration  # starts a child process (tests/conftest.py)
def test_the_cli_writes_a_site_and_refuses_a_bad_fleet_file(tmp_path):
    out = subprocess.run([sys.executable, "-m", "vsfleet.fleetctl.cli", "deploy", "config", str(DEPLOY / "fleet.toml"),
                          "--router", "tcp/10.0.0.1:7447", "--out", str(tmp_path / "site")],
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    assert (tmp_path / "site" / "r3" / "r3.json5").exists()
    assert not (tmp_path / "site" / "sim").exists()
    out = subprocess.run([sys.executable, "-m", "vsfleet.fleetctl.cli", "deploy", "config", str(DEPLOY / "fleet.toml"),
                          "--router", "tcp/10.0.0.1:7447", "--out", str(tmp_path / "sim-site"), "--sim"],
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    assert (tmp_path / "sim-site" / "sim" / "sim.json5").exists()
    bad = tmp_path / "bad.toml"
    bad.write_text((DEPLOY / "fleet.toml").read_text().replace("[robots.r3]", "[robots.tracker]"))
    out = subprocess.run([sys.executable, "-m", "vsfleet.fleetctl.cli", "deploy", "config", str(bad),
                          "--router", "tcp/10.0.0.1:7447", "--out", str(tmp_path / "x")],
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 2 and "clashes with the 'tracker' identity" in out.stderr


UNITS = sorted((DEPLOY / "systemd").glob("*.service"))
ENV = {"VSFLEET_FLEET": "lab", "VSFLEET_TTL_S": "0.3", "VSFLEET_TRACKER_ARGS": "sim"}


def exec_start(unit: Path) -> list[str]:
    """ExecStart as systemd would run it for instance r1, with vsfleet.env's defaults."""
    cp = ConfigParser(interpolation=None, strict=False)
    cp.read_string(unit.read_text())
    line = cp["Service"]["ExecStart"].replace("%i", "r1")
    for k, v in ENV.items():
        line = line.replace("${" + k + "}", v).replace("$" + k, v)
    return shlex.split(line)


@pytest.mark.parametrize("unit", UNITS, ids=[u.name for u in UNITS])
def test_each_unit_restarts_and_runs_a_command_line_its_program_accepts(unit):
    import importlib

    cp = ConfigParser(interpolation=None, strict=False)
    cp.read_string(unit.read_text())
    assert cp["Service"]["Restart"] == "always" and float(cp["Service"]["RestartSec"]) > 0
    assert cp["Unit"]["StartLimitIntervalSec"] == "0"
    argv = exec_start(unit)
    assert argv[0] == "/opt/vsfleet/.venv/bin/vsfleet"
    name = next(n for n in sorted(COMMANDS, key=len, reverse=True) if argv[1:1 + len(n.split())] == n.split())
    module = importlib.import_module(COMMANDS[name][0])
    args = module.build_parser().parse_args(argv[1 + len(name.split()):])
    assert args.config.startswith("/etc/vsfleet/")
    assert args.wait == (name != "router"), "a unit's client waits for its router, whatever its config says"
    if name == "agent":
        assert args.robot == "r1" and args.config == "/etc/vsfleet/r1.json5" and args.ttl == 0.3


@pytest.mark.parametrize("unit", UNITS, ids=[u.name for u in UNITS])
def test_each_unit_wants_and_waits_for_the_clock_to_be_synchronised(unit):
    cp = ConfigParser(interpolation=None, strict=False)
    cp.read_string(unit.read_text())
    assert "time-sync.target" in cp["Unit"]["Wants"].split()
    assert "time-sync.target" in cp["Unit"]["After"].split()


def test_the_readme_says_how_to_make_time_sync_mean_synchronised_and_what_usrpwd_protects():
    text = " ".join((DEPLOY / "README.md").read_text().split())
    assert "systemctl enable chrony-wait.service" in text
    assert "usrpwd over plain TCP only authenticates the handshake" in text


def test_the_expected_units_exist():
    assert {u.name for u in UNITS} >= {"vsfleet-agent@.service", "vsfleet-tracker.service",
                                      "vsfleet-router.service"}


@pytest.mark.integration  # starts a child process (tests/conftest.py)
@pytest.mark.skipif(shutil.which("systemd-analyze") is None, reason="needs systemd-analyze")
def test_systemd_analyze_finds_nothing_wrong_with_the_units(tmp_path):
    vsfleet = Path(sys.executable).parent / "vsfleet"
    if not vsfleet.exists():
        pytest.skip("no vsfleet console script next to this python")
    for unit in UNITS:
        (tmp_path / unit.name).write_text(unit.read_text().replace("/opt/vsfleet/.venv/bin/vsfleet", str(vsfleet)))
    out = subprocess.run(["systemd-analyze", "verify", *(str(tmp_path / u.name) for u in UNITS)],
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 0 and out.stderr.strip() == "", out.stderr


def write_conf(path: Path, mode: str | None) -> Path:
    conf = {"listen": {"endpoints": ["tcp/127.0.0.1:7447"]}, "scouting": {"multicast": {"enabled": False}}}
    if mode is not None:
        conf["mode"] = mode
    path.write_text(json.dumps(conf))
    return path


def test_vsfleet_router_runs_a_router_when_the_config_sets_no_mode(tmp_path):
    from vsfleet.fleetctl import router

    args = router.build_parser().parse_args(["--config", str(write_conf(tmp_path / "r.json5", None))])
    assert json.loads(router.router_config(args).get_json("mode")) == "router"
    args = router.build_parser().parse_args([])
    assert json.loads(router.router_config(args).get_json("mode")) == "router"


@pytest.mark.integration  # starts a child process (tests/conftest.py)
@pytest.mark.parametrize("mode, flags", [("client", []), ("peer", []), (None, ["--mode", "peer"])])
def test_vsfleet_router_refuses_another_mode_with_a_clear_message(tmp_path, mode, flags):
    conf = write_conf(tmp_path / "r.json5", mode)
    out = subprocess.run([sys.executable, "-m", "vsfleet.fleetctl.cli", "router", "--config", str(conf), *flags],
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 2
    assert "`vsfleet router` runs a router" in out.stderr
