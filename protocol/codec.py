"""The codec: messages to bytes and back (`encode`, `decode`), and the size limits it enforces.

`decode` checks the size before it parses anything, then the type name, the version and every
field (protocol/validate.py), so a garbage or forged payload is refused whole. The limits are
derived from the bounded field annotations of the catalogue (protocol/messages.py).
"""
from __future__ import annotations

import json
import types
import typing
from typing import Any, Callable, Literal, NamedTuple, TypeVar, get_args, get_origin

from .bounds import MARGIN_BYTES, MAX_DEPTH, MaxLen, Pattern, Range, bound, unwrap
from .errors import ProtocolError
from .messages import SCHEMA_VERSION, Message, bytes_field, wire_fields
from .validate import converter, deeper_than, need

M = TypeVar("M", bound=Message)


def encode(msg: Message) -> bytes:
    cls = type(msg)
    codec = _codec(cls)
    body: dict[str, Any] = {"type": cls.__name__, "v": SCHEMA_VERSION}
    for name, _required, _conv in codec.fields:
        body[name] = getattr(msg, name)
    head = _ENCODER.encode(body).encode()
    if codec.blob is None:
        return head
    return head + b"\0" + getattr(msg, codec.blob)


_ENCODER = json.JSONEncoder(separators=(",", ":"))


class _NotANumber(Exception):
    """NaN or Infinity in the text: Python's json reads them, JSON has no such tokens."""


def _refuse_constant(token: str) -> Any:
    raise _NotANumber(token)


_JSON = json.JSONDecoder(parse_constant=_refuse_constant)


def decode(data: bytes | bytearray | memoryview, expected: type[M], entries: int | None = None) -> M:
    """Bytes -> message of type `expected`, or ProtocolError naming what is wrong. `entries`: for a
    batch (one list of per-robot entries), how many robots the receiver asked about or its key names:
    the payload may then take only `batch_limit(expected, entries)` bytes."""
    name = expected.__name__
    codec = _codec(expected)
    limit = codec.max_payload if entries is None else min(codec.max_payload, batch_limit(expected, entries))
    if len(data) > limit:  # before copying or parsing anything
        raise ProtocolError(f"{name}: payload of {len(data)} bytes is over the limit of {limit}"
                            + ("" if entries is None else f" for {entries} robot(s)"))
    data = bytes(data)
    head, blob = data, b""
    if codec.blob is not None:
        head, sep, blob = data.partition(b"\0")
        if not sep:
            raise ProtocolError(f"{name}: payload lacks its binary part")
        if len(head) > codec.max_json:
            raise ProtocolError(f"{name}: JSON part of {len(head)} bytes is over the limit of {codec.max_json}")
        if len(blob) > codec.max_blob:
            raise ProtocolError(f"{name}: binary part of {len(blob)} bytes is over the limit of {codec.max_blob}")
    try:
        body = _JSON.decode(head.decode("utf-8"))
    except UnicodeDecodeError as exc:
        raise ProtocolError(f"{name}: payload is not JSON (not UTF-8 at byte {exc.start}: {data[:24]!r})") from None
    except ValueError as exc:  # malformed JSON, or an integer of more digits than Python converts
        why = exc.msg if isinstance(exc, json.JSONDecodeError) else "a number too long"
        raise ProtocolError(f"{name}: payload is not JSON ({why}; {len(data)} bytes: {data[:24]!r})") from None
    except _NotANumber as exc:
        raise ProtocolError(f"{name}: payload is not JSON ({exc.args[0]} is not a JSON number)") from None
    except RecursionError:  # the parser recurses per level: a nesting bomb ends here, not in the caller
        raise ProtocolError(f"{name}: payload nests deeper than {MAX_DEPTH} levels") from None
    if type(body) is not dict:
        raise ProtocolError(f"{name}: payload is not a JSON object")
    if body.get("type") != name:
        if "type" not in body:
            raise ProtocolError(f"expected a {name} message, got an object without a 'type'")
        raise ProtocolError(f"expected a {name} message, got type {str(body.get('type'))[:40]!r}")
    v = body.get("v")
    if type(v) is not int or v != SCHEMA_VERSION:
        raise ProtocolError(f"{name}: schema version {str(v)[:20]!r} is not supported "
                            f"(this side speaks {SCHEMA_VERSION})")
    kwargs: dict[str, Any] = {}
    for fname, required, conv in codec.fields:
        if fname in body:
            kwargs[fname] = conv(body[fname])
        elif required:
            raise ProtocolError(f"{name}: field {fname!r} is missing")
    if len(body) > len(kwargs) + 2:
        _check_unknown(name, body, codec.known)
    if codec.blob is not None:
        kwargs[codec.blob] = blob
    return expected(**kwargs)


def _check_unknown(name: str, body: dict[str, Any], known: frozenset[str]) -> None:
    """Unknown fields are ignored (a newer sender may add optional ones), but not their depth."""
    for key, value in body.items():
        if key not in known and type(value) in (list, dict) and deeper_than(value, MAX_DEPTH - 1):
            raise ProtocolError(f"{name}: field {key[:40]!r} nests deeper than {MAX_DEPTH} levels")


class _Codec(NamedTuple):
    blob: str | None
    fields: list[tuple[str, bool, Callable[[Any], Any]]]
    known: frozenset[str]
    max_json: int      # the JSON text's limit, json_limit
    max_blob: int
    max_payload: int


_CODECS: dict[type, _Codec] = {}


def _codec(cls: type[Message]) -> _Codec:
    """Per message type, once: a compiled converter per field (decode is on the hot path of every tick)."""
    if cls not in _CODECS:
        blob = bytes_field(cls)
        fields = [(f.name, f.required, converter(f.type, f"{cls.__name__}.{f.name}", 1))
                  for f in wire_fields(cls) if f.name != blob]
        max_blob = sum(need(bound(unwrap(f.type)[1], MaxLen), "binary tail", f.name).n
                       for f in wire_fields(cls) if f.name == blob)
        longest = _longest_json(cls)
        max_json = cls.json_cap_bytes if longest is None else min(
            cls.json_cap_bytes, -(-(longest + MARGIN_BYTES) // 1024) * 1024)   # whole KiB
        _CODECS[cls] = _Codec(blob, fields, frozenset({"type", "v"} | {f[0] for f in fields}), max_json, max_blob,
                              max_json + (0 if blob is None else 1 + max_blob))
    return _CODECS[cls]


def batch_limit(cls: type[Message], entries: int) -> int:
    """The most bytes a batch message (MoveBatch, MoveBatchResult, MoveAhead, MovesJudged, StateBatch)
    may take when it is for `entries` robots: its other fields at their longest, that many of its
    longest entry, and the margin for unknown fields; never more than `json_limit`. A batch's type
    allows 65,536 entries of free text, some 3 GB, capped at 8 MiB; a lone robot's answer needs 54 KiB."""
    total = len(_ENCODER.encode({"type": cls.__name__})) + len(',"v":') + _VERSION_CHARS
    for f in wire_fields(cls):
        base, meta = unwrap(f.type)
        if get_origin(base) is list:
            (item,) = get_args(base)
            n = max(0, min(entries, bound(meta, MaxLen).n))
            value = 2 + n * _longest_value(item) + max(0, n - 1)
        else:
            value = _longest_value(f.type)
        total += len(_ENCODER.encode(f.name)) + 2 + value
    return min(json_limit(cls), -(-(total + MARGIN_BYTES) // 1024) * 1024)


def json_limit(cls: type[Message]) -> int:
    """The most bytes a `cls` message's JSON text may take (a CameraFrame's before its NUL): checked by
    `decode` on the payload's length before it parses anything (docs/protocol.md, Limits)."""
    return _codec(cls).max_json


# The longest JSON text a value takes, as any JSON writer may write it without whitespace: a float
# in 24 characters (-2.2250738585072014e-308), a string character in 12 (a code point beyond the
# BMP escaped as a surrogate pair, \ud83d\ude00), a patterned string's in 1 (our patterns spell ASCII).
_FLOAT_CHARS = 24
_ESCAPED_CHAR = 12
_VERSION_CHARS = 6   # "v": a small integer


def _longest_json(cls: type[Message]) -> int | None:
    """The longest JSON text of a `cls` message's bounded fields (its binary tail aside); None if a
    field is free-form (Any), so only the type's cap bounds it."""
    blob = bytes_field(cls)
    total = len(_ENCODER.encode({"type": cls.__name__})) + len(',"v":') + _VERSION_CHARS
    for f in wire_fields(cls):
        if f.name == blob:
            continue
        n = _longest_value(f.type)
        if n is None:
            return None
        total += len(_ENCODER.encode(f.name)) + 2 + n   # ,"name":value
    return total


def _longest_value(tp: Any) -> int | None:
    base, meta = unwrap(tp)
    origin = get_origin(base)
    if base is bool:
        return len("false")
    if base is int:
        r = bound(meta, Range)
        return max(len(str(r.lo)), len(str(r.hi)))
    if base is float:
        return _FLOAT_CHARS
    if base is str:
        return 2 + bound(meta, MaxLen).n * (1 if bound(meta, Pattern) is not None else _ESCAPED_CHAR)
    if origin is Literal:
        return max(len(json.dumps(a)) for a in get_args(base))
    if origin is tuple:
        parts = [_longest_value(a) for a in get_args(base)]
        return None if None in parts else 1 + sum(parts) + len(parts)   # [a,b,c]
    if origin is list or origin is dict:
        n = bound(meta, MaxLen).n
        parts = [_longest_value(a) for a in get_args(base)]
        if None in parts:
            return None
        item = sum(parts) + (len(parts) - 1)    # a value, or "key":value
        return 2 + n * item + max(0, n - 1)
    if origin in (typing.Union, types.UnionType):
        parts = [_longest_value(a) for a in get_args(base)]
        return None if None in parts else max(parts)
    return None   # Any: free-form

