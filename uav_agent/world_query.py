"""A query of the world's over Zenoh (its info, a camera image, its record): the answer, or one
line saying that none came or that it was garbage."""
from __future__ import annotations

import time
from typing import Any

from protocol.codec import decode, encode
from protocol.errors import MissionError, ProtocolError
from protocol.transport import Transport

QUERY_TIMEOUT_S = 10.0


def query(transport: Transport, key: str, request: Any, reply_type: type, what: str,
          timeout_s: float = QUERY_TIMEOUT_S) -> Any:
    asked = time.monotonic()
    replies = transport.request(key, encode(request), timeout_s)
    if not replies:
        if time.monotonic() - asked < timeout_s / 2:   # the query ended with no reply: nobody took it or a dead camera
            raise MissionError(f"no answer from the world's {what} (its query ended unanswered)")
        raise MissionError(f"no answer from the world's {what} within {timeout_s:g} s")
    try:
        return decode(replies[0], reply_type)
    except ProtocolError as exc:
        raise MissionError(f"the world's {what} answered garbage: {exc}") from None
