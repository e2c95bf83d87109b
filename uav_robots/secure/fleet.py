"""A secure fleet's directory: a CA, one certificate and one Zenoh config per process, made and read back.

DIR gets `ca.pem`, then for each process (uav, world, robot-<id> or robots-<ids> for a
pool) `<name>.pem`, `<name>.key` (0600) and `<name>.json5`, and `fleet.json` (what it
was made for, read back by `uav-robots run --secure DIR`). The CA's own key is never
written: a new process needs a new `secure init`, so no file in DIR can mint identities.
"""
from __future__ import annotations

import dataclasses
import json
import os
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, Sequence

from protocol.bounds import MAX_ROBOTS
from protocol.errors import UavRobotsError
from protocol.keys import Keys
from protocol.security import OBSERVER, UAV, WORLD, Identity, TlsFiles, robot_identity, secure_client, secure_router

DEFAULT_PORT = 7447
MANIFEST = "fleet.json"
LOCAL_ADDRESSES = ["127.0.0.1", "localhost"]   # always in the router's certificate: local runs just work
CONNECT_TIMEOUT_MS = 20_000
# Robot processes (identities) per fleet: one ACL subject each, and one process per robot stops
# scaling near 100 anyway (NOTES: lockstep rates); pools carry the larger fleets.
MAX_ROBOT_PROCESSES = 1024
MAX_MANIFEST_BYTES = 16 * 2**20   # fleet.json of the largest fleet, one id a line: under 1 MB


@dataclass(frozen=True)
class Fleet:
    """What a secure directory was made for."""
    fleet: str
    robots: int
    groups: list[list[int]]          # robot ids per robot process
    addresses: list[str]             # where clients reach the UAV's router (in its certificate)
    port: int
    files_at: str                    # the directory as the configs name it

    def identities(self) -> list[Identity]:
        return [Identity(UAV), Identity(WORLD), Identity(OBSERVER), *(robot_identity(g) for g in self.groups)]

    def config(self, name: str) -> Path:
        return Path(self.files_at) / f"{name}.json5"


def make_fleet_dir(out: Path, fleet: Fleet) -> None:
    """Write everything for `fleet` into `out` (created 0700; keys 0600)."""
    from .certs import Authority, write_private

    out.mkdir(parents=True, exist_ok=True)
    os.chmod(out, 0o700)
    ca = Authority(f"uav-robots fleet {fleet.fleet} CA")
    (out / "ca.pem").write_bytes(ca.cert_pem)
    at = Path(fleet.files_at)
    ids = fleet.identities()
    hub_addresses = list(dict.fromkeys([*fleet.addresses, *LOCAL_ADDRESSES]))
    for who in ids:
        issued = ca.issue(who.name, hub_addresses if who.name == UAV else [])
        (out / f"{who.name}.pem").write_bytes(issued.cert_pem)
        write_private(out / f"{who.name}.key", issued.key_pem)
        files = TlsFiles(str(at / "ca.pem"), str(at / f"{who.name}.pem"), str(at / f"{who.name}.key"))
        if who.name == UAV:
            cfg = secure_router(fleet.fleet, [f"tls/{_host(a)}:{fleet.port}" for a in _listen_on(fleet.addresses)],
                                files, ids)
        else:
            cfg = secure_client([f"tls/{_host(fleet.addresses[0])}:{fleet.port}"], files, CONNECT_TIMEOUT_MS)
        (out / f"{who.name}.json5").write_text(json.dumps(cfg, indent=1) + "\n")
    (out / MANIFEST).write_text(json.dumps(asdict(fleet), indent=1) + "\n")


def _host(address: str) -> str:
    return f"[{address}]" if ":" in address else address


def _listen_on(addresses: Sequence[str]) -> list[str]:
    """Loopback only when every address is local; else every interface (TLS and the ACL guard the door)."""
    return ["127.0.0.1"] if all(a in LOCAL_ADDRESSES for a in addresses) else ["0.0.0.0"]


def read_fleet_dir(path: Path) -> Fleet:
    try:
        with (path / MANIFEST).open("rb") as f:
            raw = f.read(MAX_MANIFEST_BYTES + 1)
    except FileNotFoundError:
        raise UavRobotsError(f"--secure {path}: no {MANIFEST}: make the directory with `uav-robots secure init`") from None
    except (OSError, ValueError) as exc:   # not a directory, a name too long, a NUL byte
        raise UavRobotsError(f"--secure {str(path)[:120]!r}: cannot read {MANIFEST}: "
                             f"{getattr(exc, 'strerror', None) or exc}") from None
    if len(raw) > MAX_MANIFEST_BYTES:
        raise _damaged(path, f"is over {MAX_MANIFEST_BYTES:,} bytes")
    try:
        data = json.loads(raw)
    except (ValueError, RecursionError) as exc:   # not UTF-8 or not JSON, a number too long, nesting
        raise _damaged(path, f"is not JSON ({str(exc)[:80] or type(exc).__name__})") from None
    fleet = _fleet_from(data, path)
    # A directory made before the observer had an identity runs without a recording.
    missing = [f"{w.name}.{ext}" for w in fleet.identities() if w.name != OBSERVER for ext in ("pem", "key", "json5")
               if not _is_file(path / f"{w.name}.{ext}")]
    if missing:
        raise UavRobotsError(f"--secure {path}: missing {', '.join(missing[:3])}")
    return fleet


def _damaged(path: Path, why: str) -> UavRobotsError:
    return UavRobotsError(f"--secure {path}: {MANIFEST} {why}: make the directory again with `uav-robots secure init`")


def _fleet_from(data: Any, path: Path) -> Fleet:
    """fleet.json's object, every field checked as `secure init` wrote it: a damaged or hand-edited
    file is one line, never a traceback later."""
    if type(data) is not dict:
        raise _damaged(path, "is not a JSON object")
    for name in (f.name for f in dataclasses.fields(Fleet)):
        if name not in data:
            raise _damaged(path, f"lacks {name!r}")
    for name, kind in (("fleet", str), ("robots", int), ("groups", list), ("addresses", list), ("port", int),
                       ("files_at", str)):
        if type(data[name]) is not kind:   # not isinstance: true is no robot count
            raise _damaged(path, f"field {name!r} is not a JSON {'integer' if kind is int else kind.__name__}")
    groups, addresses = data["groups"], data["addresses"]
    if not all(type(g) is list and g and all(type(r) is int for r in g) for g in groups):
        raise _damaged(path, "field 'groups' is not lists of robot ids")
    if not addresses or not all(type(a) is str for a in addresses):
        raise _damaged(path, "field 'addresses' is not a list of host names")
    try:
        fleet = new_fleet(data["fleet"], data["robots"], groups, addresses, data["port"], Path(data["files_at"]))
    except (UavRobotsError, ValueError) as exc:
        raise _damaged(path, f"is not a fleet `secure init` makes ({str(exc)[:160]})") from None
    if sorted(r for g in groups for r in g) != list(range(fleet.robots)):
        raise _damaged(path, f"field 'groups' does not hold each robot 0..{fleet.robots - 1} once")
    return dataclasses.replace(fleet, files_at=data["files_at"])


def _is_file(path: Path) -> bool:
    try:
        return path.is_file()
    except (OSError, ValueError):   # a name too long: no such file
        return False


def new_fleet(fleet: str, robots: int, groups: list[list[int]], addresses: list[str], port: int,
              files_at: Path) -> Fleet:
    Keys(fleet)
    if not 1 <= robots <= MAX_ROBOTS:
        raise UavRobotsError(f"--robots must be in [1, {MAX_ROBOTS}], got {robots}")
    if len(groups) > MAX_ROBOT_PROCESSES:
        raise UavRobotsError(f"{len(groups)} robot processes: at most {MAX_ROBOT_PROCESSES} identities; "
                             f"host more robots per process (--robots-per-process)")
    if not 1 <= port <= 65535:
        raise UavRobotsError(f"--port must be in [1, 65535], got {port}")
    for a in addresses:
        if not a or any(c in a for c in "/[] ,"):
            raise UavRobotsError(f"--address {a!r}: give a host name or an IP address")
    return Fleet(fleet, robots, groups, addresses or ["127.0.0.1"], port, str(files_at))
