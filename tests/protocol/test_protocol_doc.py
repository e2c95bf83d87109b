"""docs/protocol.md is a contract others build from: its examples and configs must be what the code does."""
from __future__ import annotations

import json
import re
from pathlib import Path

import zenoh

from protocol import messages
from protocol.codec import decode
from protocol.config import DEFAULT_ENDPOINT, client_config, hub_config
from protocol.messages import Message

DOC = (Path(__file__).resolve().parents[2] / "docs" / "protocol.md").read_text()


def _blocks(lang: str) -> list[str]:
    return re.findall(rf"```{lang}\n(.*?)```", DOC, re.S)


def _message_types() -> dict[str, type]:
    return {c.__name__: c for c in vars(messages).values()
            if isinstance(c, type) and issubclass(c, Message) and c is not Message}


def test_every_message_has_an_example_that_decodes():
    types = _message_types()
    seen = set()
    for block in _blocks("json"):
        for line in filter(None, block.splitlines()):
            name = json.loads(line)["type"]
            payload = line.encode()
            if name == "CameraFrame":
                payload += b"\0\x89PNG"
            decode(payload, types[name])
            seen.add(name)
    assert seen == set(types), f"no example for {sorted(set(types) - seen)}"


def _settings(cfg: zenoh.Config, keys: list[str]) -> dict[str, object]:
    return {k: json.loads(cfg.get_json(k)) for k in keys}


def test_the_documented_zenoh_configs_are_the_generated_ones():
    router, client = _blocks("json5")[:2]   # the Sessions section's two, first in the document
    keys = ["mode", "listen/endpoints", "scouting/multicast/enabled"]
    assert _settings(zenoh.Config.from_json5(router), keys) == \
        _settings(zenoh.Config.from_json5(hub_config([DEFAULT_ENDPOINT])), keys)
    keys = ["mode", "connect/endpoints", "connect/timeout_ms", "connect/retry", "scouting/multicast/enabled",
            "transport/link/tx/lease"]
    assert _settings(zenoh.Config.from_json5(client), keys) == \
        _settings(zenoh.Config.from_json5(client_config([DEFAULT_ENDPOINT])), keys)


def test_every_robot_status_is_defined():
    defined = set(re.findall(r"^\| `(\w+)` \|", DOC[DOC.index("**Robot status**"):], re.M)[:5])
    assert defined == set(messages.Status.__args__)
