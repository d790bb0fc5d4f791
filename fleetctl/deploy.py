"""vsfleet deploy config: zenoh configs with authentication and access control for real hosts.

Writes, per host, what goes into its /etc/vsfleet: the router's config (access
control, user/password dictionary or mTLS), one client config per identity
(tracker, operator, one agent per robot, and sim if asked for) and a vsfleet.env
for systemd. Files with credentials (client configs, the password dictionary,
private keys) are created mode 0600 and installed root:vsfleet 0640 on the hosts
(deploy/README.md).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import logging
import os
import secrets
import shutil
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

from vsfleet.wire import Keys, WireError, check_name

from vsfleet.zglue.program import common_flags
from vsfleet.zglue.scenario_file import load_scenario

log = logging.getLogger("vsfleet.deploy")

SERVICE_IDENTITIES = ("tracker", "sim", "operator")
# names the config already uses: the router's certificate and directory, the CA's directory, the
# ACL subject of every login, the agents' liveliness role; a robot may not be called that either
RESERVED_IDS = ("router", "pki", "everyone", "agent")
AUTH_MODES = ("usrpwd", "mtls")
# Services wait for the router forever and retry quickly after losing it; the
# operator's one-shot commands fail after CONNECT_TIMEOUT_OPERATOR_MS instead.
RETRY = {"period_init_ms": 250, "period_max_ms": 2000, "period_increase_factor": 2}
CONNECT_TIMEOUT_OPERATOR_MS = 10000

READ_MESSAGES = ["declare_subscriber", "declare_liveliness_subscriber", "liveliness_query", "query"]
DELIVER_MESSAGES = ["put", "declare_subscriber", "declare_queryable", "liveliness_token", "query", "reply"]


class DeployError(ValueError):
    """Bad input to the config generator (fleet, robots, endpoints, auth mode)."""


def identities(robots: list[str] | tuple[str, ...], sim: bool = False) -> tuple[str, ...]:
    """Every login of a fleet: tracker, (sim, if asked for,) operator, then one per robot (its agent)."""
    for r in robots:
        try:
            check_name(r, "robot id")
        except WireError as exc:
            raise DeployError(str(exc)) from None
        if r in SERVICE_IDENTITIES:
            raise DeployError(f"robot id {r!r} clashes with the {r!r} identity; rename the robot")
        if r in RESERVED_IDS:
            raise DeployError(f"robot id {r!r} is reserved (the config uses {', '.join(RESERVED_IDS)} "
                              f"itself); rename the robot")
    if len(set(robots)) != len(robots) or not robots:
        raise DeployError(f"robots must be distinct and at least one, got {list(robots)}")
    return (*(i for i in SERVICE_IDENTITIES if sim or i != "sim"), *robots)


def _rule(rule_id: str, flow: str, messages: list[str], key_exprs: list[str]) -> dict:
    return {"id": rule_id, "permission": "allow", "flows": [flow], "messages": messages,
            "key_exprs": key_exprs}


def access_control(fleet: str, robots: list[str] | tuple[str, ...], auth: str = "usrpwd",
                   sim: bool = False) -> dict:
    """The router's ``access_control`` block: default deny, then what each identity may do.

    Flows are the router's: ``ingress`` is what a client sends, ``egress`` what it is sent.
    Subjects match the usrpwd user name, or the certificate's common name under mTLS.
    Agent rN answers queries only under ``vs/<fleet>/peer/rN/**`` and puts events only on
    ``event/rN``, so no robot's login can answer or decide for another.
    """
    if auth not in AUTH_MODES:
        raise DeployError(f"auth must be one of {AUTH_MODES}, got {auth!r}")
    try:
        p = Keys(fleet).prefix
    except WireError as exc:
        raise DeployError(str(exc)) from None
    ids = identities(robots, sim)
    k = Keys(fleet)
    match = "usernames" if auth == "usrpwd" else "cert_common_names"
    rules = [
        _rule("read", "ingress", READ_MESSAGES, [f"{p}/**"]),
        _rule("deliver", "egress", DELIVER_MESSAGES, [f"{p}/**"]),
        _rule("tracker-pose", "ingress", ["put"], [f"{p}/frame/**", f"{p}/pose/**"]),
        _rule("tracker-alive", "ingress", ["liveliness_token"], [f"{p}/alive/tracker/*"]),
    ]
    if sim:
        rules += [_rule("sim-truth", "ingress", ["put"], [f"{p}/truth/**", f"{p}/contact/**"]),
                  _rule("sim-alive", "ingress", ["liveliness_token"], [f"{p}/alive/sim/*"])]
    rules += [
        _rule("operator-put", "ingress", ["put"], [k.mission, f"{p}/fault/**"]),
        _rule("operator-answer", "ingress", ["declare_queryable", "reply"], [k.mission]),
        _rule("admin-query", "ingress", ["query"], ["@/**"]),
        _rule("admin-reply", "egress", ["reply"], ["@/**"]),
    ]
    subjects = [{"id": "everyone", match: list(ids)}] + [{"id": i, match: [i]} for i in ids]
    policies = [
        {"id": "everyone", "rules": ["read", "deliver"], "subjects": ["everyone"]},
        {"id": "tracker", "rules": ["tracker-pose", "tracker-alive"], "subjects": ["tracker"]},
    ]
    if sim:
        policies.append({"id": "sim", "rules": ["sim-truth", "sim-alive"], "subjects": ["sim"]})
    policies.append({"id": "operator", "rules": ["operator-put", "operator-answer", "admin-query", "admin-reply"],
                     "subjects": ["operator"]})
    for r in robots:
        rules.append(_rule(f"agent-{r}-put", "ingress", ["put"], [k.cmd(r), k.state(r), k.event(r)]))
        rules.append(_rule(f"agent-{r}-alive", "ingress", ["liveliness_token"], [k.alive("agent", r)]))
        rules.append(_rule(f"agent-{r}-answer", "ingress", ["declare_queryable", "reply"], [f"{k.peer(r)}/**"]))
        policies.append({"id": f"agent-{r}", "rules": [f"agent-{r}-put", f"agent-{r}-alive", f"agent-{r}-answer"],
                         "subjects": [r]})
    return {"enabled": True, "default_permission": "deny", "rules": rules, "subjects": subjects,
            "policies": policies}


@dataclass(frozen=True)
class Tls:
    """Paths (as seen on the host that uses the config) of the CA and of this host's key pair."""

    ca: str
    certificate: str
    private_key: str


def router_config(fleet: str, robots, listen: list[str], auth: str = "usrpwd",
                  dictionary_file: str | None = None, tls: Tls | None = None, sim: bool = False) -> dict:
    """A router-mode config: listens on ``listen``, no scouting, admin space on, access control on."""
    if not listen:
        raise DeployError("the router needs at least one listen endpoint, e.g. tcp/0.0.0.0:7447")
    conf: dict = {
        "mode": "router",
        "listen": {"endpoints": list(listen)},
        "scouting": {"multicast": {"enabled": False}, "gossip": {"enabled": False}},
        "adminspace": {"enabled": True},
        "access_control": access_control(fleet, robots, auth, sim),
    }
    if auth == "usrpwd":
        if not dictionary_file:
            raise DeployError("usrpwd auth needs the router's password dictionary file")
        conf["transport"] = {"auth": {"usrpwd": {"dictionary_file": dictionary_file}}}
    else:
        if tls is None:
            raise DeployError("mtls auth needs the router's CA, certificate and key")
        conf["transport"] = {"link": {"tls": {
            "root_ca_certificate": tls.ca, "listen_certificate": tls.certificate,
            "listen_private_key": tls.private_key, "enable_mtls": True}}}
    return conf


def client_config(identity: str, connect: list[str], auth: str = "usrpwd", password: str | None = None,
                  tls: Tls | None = None) -> dict:
    """A client-mode config that logs in as ``identity``; services wait for the router forever."""
    if not connect:
        raise DeployError("a client needs the router's endpoint, e.g. tcp/ROUTER_HOST:7447")
    operator = identity == "operator"
    conf: dict = {
        "mode": "client",
        "connect": {"endpoints": list(connect),
                    "timeout_ms": CONNECT_TIMEOUT_OPERATOR_MS if operator else -1,
                    "exit_on_failure": operator, "retry": dict(RETRY)},
        "scouting": {"multicast": {"enabled": False}},
    }
    if auth == "usrpwd":
        if not password:
            raise DeployError(f"usrpwd auth needs a password for {identity!r}")
        conf["transport"] = {"auth": {"usrpwd": {"user": identity, "password": password}}}
    elif auth == "mtls":
        if tls is None:
            raise DeployError(f"mtls auth needs {identity!r}'s CA, certificate and key")
        conf["transport"] = {"link": {"tls": {
            "root_ca_certificate": tls.ca, "connect_certificate": tls.certificate,
            "connect_private_key": tls.private_key, "enable_mtls": True}}}
    else:
        raise DeployError(f"auth must be one of {AUTH_MODES}, got {auth!r}")
    return conf


def _compact(value, indent: int = 0, width: int = 100) -> str:
    """JSON with every value that fits in ``width`` columns on one line."""
    flat = json.dumps(value)
    if len(flat) + indent <= width or not isinstance(value, (dict, list)) or not value:
        return flat
    pad = " " * (indent + 2)
    if isinstance(value, dict):
        items = [f"{pad}{json.dumps(k)}: {_compact(v, indent + 2, width)}" for k, v in value.items()]
        return "{\n" + ",\n".join(items) + "\n" + " " * indent + "}"
    items = [f"{pad}{_compact(v, indent + 2, width)}" for v in value]
    return "[\n" + ",\n".join(items) + "\n" + " " * indent + "]"


def json5_text(conf: dict, header: str) -> str:
    """A config as JSON (valid JSON5) under ``//`` comment lines."""
    comments = "".join(f"// {line}\n" for line in header.splitlines())
    return comments + _compact(conf) + "\n"


@contextlib.contextmanager
def private_files() -> Iterator[None]:
    """Files created meanwhile (also by child processes: openssl) are mode 0600 or stricter."""
    old = os.umask(0o077)
    try:
        yield
    finally:
        os.umask(old)


def write_secret(path: Path, text: str) -> None:
    """Write ``text`` to ``path``, mode 0600 from the moment it exists (also if it existed)."""
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(fd, "w") as f:
        os.fchmod(fd, 0o600)
        f.write(text)


def _openssl(*args: str) -> None:
    out = subprocess.run(["openssl", *args], capture_output=True, text=True)
    if out.returncode != 0:
        raise DeployError(f"openssl {args[0]} failed: {out.stderr.strip()}")


def make_certs(pki: Path, router_hosts: list[str], names: tuple[str, ...], days: int = 825) -> None:
    """A CA (kept if present) and one EC key pair per name, CN = name; the router's carries SANs.

    The router's certificate is for TLS servers only (extendedKeyUsage serverAuth), every
    other one for TLS clients only (clientAuth). Keys are created mode 0600. Needs the
    openssl CLI. ``router_hosts`` are the names/addresses clients dial.
    """
    if shutil.which("openssl") is None:
        raise DeployError("mtls needs the openssl command-line tool to make certificates")
    pki.mkdir(parents=True, exist_ok=True)
    ec = ["-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:prime256v1", "-nodes"]
    ca, ca_key = pki / "ca.pem", pki / "ca.key"
    with private_files():
        if not ca.exists():
            _openssl("req", "-x509", *ec, "-days", str(days), "-subj", "/CN=vsfleet-ca",
                     "-keyout", str(ca_key), "-out", str(ca))
        for name in ("router", *names):
            sans = [f"IP:{h}" if h.replace(".", "").isdigit() or ":" in h else f"DNS:{h}"
                    for h in (router_hosts if name == "router" else [])] or [f"DNS:{name}"]
            usage = "serverAuth" if name == "router" else "clientAuth"
            ext = pki / f"{name}.ext"
            ext.write_text(f"subjectAltName={','.join(sans)}\nbasicConstraints=CA:FALSE\n"
                           f"keyUsage=digitalSignature\nextendedKeyUsage={usage}\n")
            _openssl("req", *ec, "-subj", f"/CN={name}", "-keyout", str(pki / f"{name}.key"),
                     "-out", str(pki / f"{name}.csr"))
            _openssl("x509", "-req", "-in", str(pki / f"{name}.csr"), "-CA", str(ca), "-CAkey", str(ca_key),
                     "-CAcreateserial", "-days", str(days), "-extfile", str(ext),
                     "-out", str(pki / f"{name}.pem"))
            (pki / f"{name}.csr").unlink()
            ext.unlink()
    for public in ca, *(pki / f"{n}.pem" for n in ("router", *names)):
        os.chmod(public, 0o644)  # certificates are public


def _host_of(endpoint: str) -> str:
    """``tcp/10.0.0.1:7447`` -> ``10.0.0.1``; ``tls/[::1]:7447`` -> ``::1``."""
    try:
        addr = endpoint.split("/", 1)[1].split("#", 1)[0]
        host = addr.rsplit(":", 1)[0]
    except IndexError:
        raise DeployError(f"endpoint must look like tcp/HOST:PORT, got {endpoint!r}") from None
    return host.strip("[]")


def env_text(fleet: str, ttl_s: float = 0.3, tracker_args: str = "sim") -> str:
    """/etc/vsfleet/vsfleet.env, read by the systemd units."""
    return (f"# read by the vsfleet-*.service units\nVSFLEET_FLEET={fleet}\nVSFLEET_TTL_S={ttl_s}\n"
            f"# sim (simulated tracker, with vsfleet-sim.service), or e.g.\n"
            f"# camera --camera /etc/vsfleet/camera.toml --calibration /etc/vsfleet/calibration.json --source 0\n"
            f"VSFLEET_TRACKER_ARGS={tracker_args}\n")


def _copy_private(src: Path, dst: Path) -> None:
    """Copy a private key: the copy is mode 0600 from the moment it exists."""
    dst.unlink(missing_ok=True)
    with private_files():
        shutil.copy2(src, dst)
    os.chmod(dst, 0o600)


def write_deploy(out: Path, fleet: str, robots, router_endpoint: str, auth: str = "usrpwd",
                 conf_dir: str = "/etc/vsfleet", listen: list[str] | None = None,
                 passwords: dict[str, str] | None = None, fleet_file: Path | None = None,
                 sim: bool = False) -> dict[str, Path]:
    """Write OUT/<host role>/ for the router and every identity; returns {identity: client config path}.

    OUT/router holds router.json5 plus the password dictionary (or its certificates);
    OUT/<identity> holds <identity>.json5, its certificates, vsfleet.env and (sim, operator)
    the fleet file. Copy each directory to that host's ``conf_dir``. Passwords are random
    unless given. The ``sim`` login (simulated robots, which may put truth) only if asked for.
    Files with credentials are created mode 0600 (never readable by others, not even for a moment).
    """
    ids = identities(tuple(robots), sim)
    proto = "tls" if auth == "mtls" else "tcp"
    if not router_endpoint.startswith(f"{proto}/"):
        raise DeployError(f"with auth {auth} the router endpoint must start with {proto}/, "
                          f"got {router_endpoint!r}")
    port = router_endpoint.rsplit(":", 1)[-1]
    listen = listen or [f"{proto}/0.0.0.0:{port}"]
    out.mkdir(parents=True, exist_ok=True)
    header = (f"vsfleet fleet {fleet!r}: generated by `vsfleet deploy config`; auth {auth}.\n"
              f"It holds credentials: install into {conf_dir}/ on the host as root:vsfleet, mode 0640\n"
              f"(the operator's own copy: mode 0600), as deploy/README.md says.")
    paths: dict[str, Path] = {}
    (out / "router").mkdir(exist_ok=True)
    if auth == "usrpwd":
        passwords = dict(passwords or {})
        for i in ids:
            passwords.setdefault(i, secrets.token_urlsafe(18))
        bad = [i for i, pw in passwords.items() if not pw or ":" in pw or "\n" in pw]
        if bad:
            raise DeployError(f"passwords must be non-empty without ':' or newlines: {bad}")
        write_secret(out / "router" / "passwords", "".join(f"{i}:{passwords[i]}\n" for i in ids))
        router = router_config(fleet, robots, listen, auth, dictionary_file=f"{conf_dir}/passwords", sim=sim)
    else:
        pki = out / "pki"
        make_certs(pki, [_host_of(router_endpoint)], ids)
        router_tls = Tls(f"{conf_dir}/ca.pem", f"{conf_dir}/router.pem", f"{conf_dir}/router.key")
        for name in ("router", *ids):
            (out / name).mkdir(exist_ok=True)
            for f in ("ca.pem", f"{name}.pem"):
                shutil.copy2(pki / f, out / name / f)
            _copy_private(pki / f"{name}.key", out / name / f"{name}.key")
        router = router_config(fleet, robots, listen, auth, tls=router_tls, sim=sim)
    write_secret(out / "router" / "router.json5", json5_text(router, header))
    for i in ids:
        (out / i).mkdir(exist_ok=True)
        if auth == "usrpwd":
            conf = client_config(i, [router_endpoint], auth, password=passwords[i])
        else:
            conf = client_config(i, [router_endpoint], auth,
                                 tls=Tls(f"{conf_dir}/ca.pem", f"{conf_dir}/{i}.pem", f"{conf_dir}/{i}.key"))
        path = out / i / f"{i}.json5"
        write_secret(path, json5_text(conf, header))
        (out / i / "vsfleet.env").write_text(env_text(fleet))
        if fleet_file is not None and i in ("sim", "operator"):
            shutil.copy2(fleet_file, out / i / "fleet.toml")
        paths[i] = path
    (out / "router" / "vsfleet.env").write_text(env_text(fleet))
    return paths


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="vsfleet deploy config", description=__doc__.splitlines()[0])
    p.add_argument("fleet_file", help="fleet/scenario TOML: its [fleet] name and [robots] ids are used")
    p.add_argument("--router", required=True, metavar="ENDPOINT",
                   help="the router as clients dial it, e.g. tcp/10.0.0.1:7447 (tls/... with --auth mtls)")
    p.add_argument("--out", required=True, help="output directory, one subdirectory per host role")
    p.add_argument("--fleet", default=None, help="override the file's fleet name")
    p.add_argument("--auth", choices=AUTH_MODES, default="usrpwd",
                   help="usrpwd: passwords in a dictionary file; mtls: certificates (openssl CLI)")
    p.add_argument("--conf-dir", default="/etc/vsfleet", help="where the files live on the hosts")
    p.add_argument("--listen", action="append", default=[], metavar="ENDPOINT",
                   help="router listen endpoint (default: 0.0.0.0 on the --router port)")
    p.add_argument("--sim", action="store_true",
                   help="also make the `sim` login, which may publish truth (simulated robots, "
                        "vsfleet-sim.service); not for a lab with real robots")
    return common_flags(p, zenoh=False)


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)  # not under @program: its lines are plain, for an operator
    logging.basicConfig(level=logging.DEBUG if args.verbose else logging.INFO, format="%(message)s")
    try:
        scenario = load_scenario(args.fleet_file, args.fleet)
        paths = write_deploy(Path(args.out), scenario.fleet, [r.robot for r in scenario.robots],
                             args.router, args.auth, args.conf_dir, args.listen or None,
                             fleet_file=Path(args.fleet_file), sim=args.sim)
    except (OSError, ValueError) as exc:
        print(f"vsfleet deploy config: {exc}", file=sys.stderr)
        return 2
    log.info("fleet %s: wrote %s/router and %s", scenario.fleet, args.out,
             ", ".join(str(p.parent) for p in paths.values()))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
