"""Zenoh configs for a fleet that trusts no stranger: mutual TLS and access control (pure functions).

Every process holds a certificate from the fleet's own CA; its common name is its
identity: `uav`, `world`, `robot-<id>` for a lone robot, `robots-<ids>` for a pool, and
`observer` for a recorder that may only listen.
The UAV is the router, so its config carries the access control: default deny,
and each identity may send (ingress) and receive (egress) only what its role
needs (docs/protocol.md, *Security*). The UAV's own messages are local to the
router and pass without rules: it is the trusted centre of the fleet.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Sequence

from .config import LEASE_MS, client_dict, hub_dict
from .keys import Keys, format_ids

UAV, WORLD, OBSERVER = "uav", "world", "observer"


@dataclass(frozen=True)
class Identity:
    name: str                      # the certificate's common name, and the stem of its files
    robots: tuple[int, ...] = ()   # the robots it hosts (robot identities only)


def robot_identity(ids: Sequence[int]) -> Identity:
    ids = tuple(sorted(ids))
    name = f"robot-{ids[0]}" if len(ids) == 1 else f"robots-{format_ids(ids).replace(',', '_')}"
    return Identity(name, ids)


@dataclass(frozen=True)
class TlsFiles:
    """Paths as the process will see them (relative paths are relative to its working directory)."""
    ca: str
    cert: str
    key: str


def tls_section(files: TlsFiles, listens: bool) -> dict[str, Any]:
    tls: dict[str, Any] = {"root_ca_certificate": files.ca, "connect_certificate": files.cert,
                           "connect_private_key": files.key, "enable_mtls": True,
                           # Clients check that the router's certificate names the address they dialled.
                           "verify_name_on_connect": True}
    if listens:
        tls.update({"listen_certificate": files.cert, "listen_private_key": files.key})
    return tls


def _rule(rid: str, messages: list[str], flow: str, keys: list[str]) -> dict[str, Any]:
    return {"id": rid, "messages": messages, "flows": [flow], "permission": "allow", "key_exprs": keys}


def _grants(k: Keys, who: Identity) -> list[tuple[list[str], str, list[str]]]:
    """(messages, flow, key expressions) an identity is allowed; ingress is what it sends to the router."""
    alive_uav = [k.alive_uav]
    if who.name == OBSERVER:
        # Reads every put of the fleet (the recording, the live view); sends nothing ...
        return [
            (["declare_subscriber"], "ingress", [f"{k.prefix}/**"]),
            (["put"], "egress", [f"{k.prefix}/**"]),
            # ... and says it listens, so that a UAV told to wait for it takes off recorded.
            (["liveliness_token"], "ingress", [k.alive_observers]),
        ]
    if who.name == WORLD:
        return [
            (["declare_queryable", "reply"], "ingress", [f"{k.prefix}/world/**"]),
            (["query"], "egress", [f"{k.prefix}/world/**"]),
            # Moves put ahead (a put, not a query) and the tick, to judge them when it comes;
            # the answers are put back, one key per sender.
            (["declare_subscriber"], "ingress", [k.mission_end, k.tick, k.all_ahead]),
            (["put"], "egress", [k.mission_end, k.tick, k.all_ahead]),
            (["put"], "ingress", [f"{k.prefix}/world/judged/*", k.world_movers]),   # the movers: for observers
            (["declare_subscriber"], "egress", [f"{k.prefix}/world/judged/*"]),
            (["liveliness_token"], "ingress", [k.alive_world]),
            (["declare_liveliness_subscriber", "liveliness_query"], "ingress", [*alive_uav, k.alive_robots]),
            (["liveliness_token", "reply"], "egress", [*alive_uav, k.alive_robots]),
        ]
    ids = who.robots
    plans = [k.plan(r) for r in ids]
    move = [k.move_as(ids)]
    return [
        (["put"], "ingress", [key for r in ids for key in (k.ack(r), k.state(r), k.done(r))]
         + [k.states_as(ids), k.ahead_as(ids)]),
        (["liveliness_token"], "ingress", [k.alive_robot(r) for r in ids]),
        # A pool subscribes to every plan with one wildcard (one callback thread); egress still
        # delivers only its own robots' plans.
        (["declare_subscriber"], "ingress", [*(plans if len(ids) == 1 else [f"{k.prefix}/robot/*/plan"]),
                                             k.tick, k.mission_end, k.judged_as(ids)]),
        (["put"], "egress", [*plans, k.tick, k.mission_end, k.judged_as(ids)]),
        (["declare_liveliness_subscriber", "liveliness_query"], "ingress", alive_uav),
        (["liveliness_token", "reply"], "egress", alive_uav),
        (["query"], "ingress", move),
        (["reply"], "egress", move),
        # Where its puts and queries are wanted: a client sends nothing towards a key nobody declared.
        (["declare_subscriber"], "egress", [f"{k.prefix}/robot/*/{x}" for x in ("ack", "state", "done")]
         + [key for r in ids for key in (k.ack(r), k.state(r), k.done(r))] + [k.all_state_batches, k.states_as(ids)]
         + [k.all_ahead, k.ahead_as(ids)]),
        (["declare_queryable"], "egress", [k.move, k.moves_by_identity]),
    ]


def access_control(fleet: str, identities: Sequence[Identity]) -> dict[str, Any]:
    """Zenoh's `access_control` section: default deny, one subject and policy per identity."""
    k = Keys(fleet)
    rules: list[dict[str, Any]] = []
    subjects: list[dict[str, Any]] = []
    policies: list[dict[str, Any]] = []
    for who in identities:
        if who.name == UAV:
            continue   # the router itself: its messages never cross one of its links
        ids = []
        for i, (messages, flow, keys) in enumerate(_grants(k, who)):
            ids.append(f"{who.name}/{i}")
            rules.append(_rule(ids[-1], messages, flow, keys))
        subjects.append({"id": who.name, "cert_common_names": [who.name]})
        policies.append({"id": who.name, "rules": ids, "subjects": [who.name]})
    return {"enabled": True, "default_permission": "deny", "rules": rules, "subjects": subjects,
            "policies": policies}


def secure_router(fleet: str, listen: list[str], files: TlsFiles, identities: Sequence[Identity]) -> dict[str, Any]:
    cfg = hub_dict(listen)
    cfg["transport"] = {"link": {"protocols": ["tls"], "tls": tls_section(files, listens=True)}}
    cfg["access_control"] = access_control(fleet, identities)
    return cfg


def secure_client(connect: list[str], files: TlsFiles, timeout_ms: int, lease_ms: int = LEASE_MS) -> dict[str, Any]:
    cfg = client_dict(connect, timeout_ms, lease_ms)
    cfg["transport"]["link"].update({"protocols": ["tls"], "tls": tls_section(files, listens=False)})
    return cfg
