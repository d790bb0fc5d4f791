"""The mission a running fleet holds, asked of the operator's tool and of the agents.

Agents answer mission queries under their own key (``vs/<fleet>/peer/<robot>/mission``);
only the operator's login may answer on ``vs/<fleet>/mission``. A tool that
starts while a fleet runs (``vsfleet record``, ``vsfleet monitor``) takes the
operator's answer, else the answer a strict majority of the agents that replied
give (vsfleet.quorum), as an agent does.
"""

from __future__ import annotations

import logging

import zenoh

from vsfleet.quorum import majority
from vsfleet.wire import NAME_RE

log = logging.getLogger("vsfleet.peers")


def current_missions(session: zenoh.Session, fleet: str | None = None,
                     timeout_s: float = 2.0) -> list[tuple[str, bytes]]:
    """[(``vs/<fleet>/mission``, payload)] for ``fleet`` (every fleet if None): every distinct
    operator answer, or else the agents' majority answer."""
    f = fleet or "*"
    gets = [session.get(sel, timeout=timeout_s, target=zenoh.QueryTarget.ALL,
                        consolidation=zenoh.ConsolidationMode.NONE)
            for sel in (f"vs/{f}/mission", f"vs/{f}/peer/*/mission")]
    operator: dict[str, list[bytes]] = {}
    peers: dict[str, list[tuple[str, bytes]]] = {}
    for handler in gets:
        for reply in handler:
            if reply.ok is None:
                continue
            parts = str(reply.ok.key_expr).split("/")
            payload = reply.ok.payload.to_bytes()
            if len(parts) == 3 and parts[2] == "mission" and NAME_RE.match(parts[1]):
                if payload not in operator.setdefault(parts[1], []):
                    operator[parts[1]].append(payload)
            elif len(parts) == 5 and parts[2] == "peer" and parts[4] == "mission" and NAME_RE.match(parts[1]):
                peers.setdefault(parts[1], []).append((parts[3], payload))
    out = []
    for name in sorted(set(operator) | set(peers)):
        key = f"vs/{name}/mission"
        if name in operator:
            out.extend((key, p) for p in operator[name])
            continue
        verdict = majority(peers[name])
        if verdict.answer is None:
            log.warning("fleet %s: no mission taken from the agents: %s", name, verdict.why)
        else:
            out.append((key, verdict.answer))
    return out
