"""Validation: a checking converter per field type, compiled once from its bounded annotation.

A converter takes a value as JSON decoded it and returns it as the message field holds it, or
raises ProtocolError with one line naming the field, what was expected and (briefly) what came.
The codec (protocol/codec.py) builds one per field of every message type.
"""
from __future__ import annotations

import json
import re
import types
import typing
from typing import Any, Callable, Literal, get_args, get_origin

from .bounds import MAX_DEPTH, MAX_FLOAT, MaxLen, Pattern, Range, bound, unwrap
from .errors import ProtocolError

def deeper_than(value: Any, limit: int) -> bool:
    """Whether `value` nests more than `limit` arrays and objects; level by level, so no recursion."""
    level = [value]
    for _ in range(limit):
        level = [y for x in level if type(x) in (list, dict) for y in (x.values() if type(x) is dict else x)]
        if not level:
            return False
    return any(type(x) in (list, dict) for x in level)


def _show(v: Any) -> str:
    """A received value in an error line: short whatever it is."""
    if type(v) is int:
        return str(v) if v.bit_length() <= 64 else f"a {v.bit_length()}-bit int"
    if type(v) is float:
        return repr(v)
    if type(v) is str:
        return repr(v) if len(v) <= 24 else f"str of {len(v)} characters"
    if type(v) is list and len(v) <= 4 and all(type(x) in (int, float, bool) or x is None for x in v):
        text = json.dumps(v)  # a cell, say: its values are the news
        if len(text) <= 48:
            return text
    if type(v) in (list, dict):
        return f"{type(v).__name__} of {len(v)}"
    return "null" if v is None else type(v).__name__


def _fail(where: str, expected: str, value: Any) -> ProtocolError:
    return ProtocolError(f"{where}: expected {expected}, got {_show(value)}")


def need(meta: Any, what: str, where: str) -> Any:
    if meta is None:  # every field that sizes memory must say its bound: a schema author's mistake
        raise TypeError(f"{where}: unbounded {what} in a message schema")
    return meta


def converter(tp: Any, where: str, outer: int) -> Callable[[Any], Any]:
    """A checking converter for a JSON value of type `tp` that sits inside `outer` arrays/objects."""
    base, meta = unwrap(tp)
    origin = get_origin(base)
    if base is Any:
        return _any_converter(where, MAX_DEPTH - outer)
    if base is bool:
        def conv(v: Any) -> Any:
            if v is True or v is False:
                return v
            raise _fail(where, "bool", v)
        return conv
    if base is int or base is float:
        return _number_converter(base, need(bound(meta, Range), "number", where), where)
    if base is str:
        return _text_converter(need(bound(meta, MaxLen), "string", where).n, bound(meta, Pattern), where)
    if origin is Literal:
        # Literal strings or integers; `type(v) in kinds` keeps true out of an integer enum.
        allowed = frozenset(get_args(base))
        kinds = {type(a) for a in allowed}
        expected = "one of " + ", ".join(sorted(map(str, allowed)))

        def conv(v: Any) -> Any:
            if type(v) in kinds and v in allowed:
                return v
            raise _fail(where, expected, v)
        return conv
    if origin is tuple:
        return _tuple_converter(get_args(base), where, outer)
    if origin is list:
        return _list_converter(get_args(base)[0], need(bound(meta, MaxLen), "list", where).n, where, outer)
    if origin is dict:
        return _dict_converter(get_args(base), need(bound(meta, MaxLen), "object", where).n, where, outer)
    if origin in (typing.Union, types.UnionType):
        options = [converter(a, where, outer) for a in get_args(base)]

        def conv(v: Any) -> Any:
            for c in options:
                try:
                    return c(v)
                except ProtocolError:
                    pass
            raise _fail(where, " or ".join(str(a) for a in get_args(base)), v)
        return conv
    raise TypeError(f"unsupported schema type {tp} at {where}")  # a schema author's mistake, not bad input


def _any_converter(where: str, room: int) -> Callable[[Any], Any]:
    def conv(v: Any) -> Any:
        if type(v) in (list, dict) and deeper_than(v, room):
            raise ProtocolError(f"{where}: nests deeper than {MAX_DEPTH} levels")
        return v
    return conv


def _number_converter(base: type, r: Range, where: str) -> Callable[[Any], Any]:
    lo, hi = r.lo, r.hi
    if base is int:
        expected = f"int in [{lo}, {hi}]"

        def conv(v: Any) -> Any:
            if type(v) is int and lo <= v <= hi:
                return v
            raise _fail(where, expected, v)
        return conv
    # JSON writes 2.0 as 2 in some languages: ints are numbers too. NaN fails every comparison.
    expected = ("finite float" if lo == -MAX_FLOAT and hi == MAX_FLOAT else
                f"finite float {'>' if r.open_lo else '>='} {lo:g}" if hi == MAX_FLOAT else
                f"float in {'(' if r.open_lo else '['}{lo:g}, {hi:g}]")
    if r.open_lo:
        def conv(v: Any) -> Any:
            if (type(v) is float or type(v) is int) and lo < v <= hi:
                return float(v)
            raise _fail(where, expected, v)
        return conv

    def conv(v: Any) -> Any:
        if (type(v) is float or type(v) is int) and lo <= v <= hi:
            return float(v)
        raise _fail(where, expected, v)
    return conv


def _unicode(text: str) -> bool:
    """JSON escapes can spell lone surrogates, which no UTF-8 writer (nor a log line) accepts."""
    try:
        text.encode("utf-8")
    except UnicodeEncodeError:
        return False
    return True


def _text_converter(n: int, pattern: Pattern | None, where: str) -> Callable[[Any], Any]:
    match = re.compile(pattern.regex).fullmatch if pattern is not None else None

    def conv(v: Any) -> Any:
        if type(v) is not str or len(v) > n:
            _check_sized(v, str, n, where)   # raises, naming the problem
        if not (v.isascii() or _unicode(v)):
            raise ProtocolError(f"{where}: text holds a lone surrogate, not Unicode")
        if match is not None and match(v) is None:
            raise _fail(where, f"text matching {pattern.regex}", v)
        return v
    return conv


def _tuple_converter(args: tuple[Any, ...], where: str, outer: int) -> Callable[[Any], Any]:
    n = len(args)
    first, meta = unwrap(args[0])
    if n == 2 and first is int and args[0] == args[1]:  # cells: the most common shape by far, inlined
        r = need(bound(meta, Range), "number", where)
        lo, hi, expected = r.lo, r.hi, f"[int, int] in [{r.lo}, {r.hi}]"

        def conv(v: Any) -> Any:
            if type(v) is list and len(v) == 2:
                x, y = v
                if type(x) is int and type(y) is int and lo <= x <= hi and lo <= y <= hi:
                    return (x, y)
            raise _fail(where, expected, v)
        return conv
    parts = [converter(a, f"{where}[{i}]", outer + 1) for i, a in enumerate(args)]
    # The batches' entries (3 to 5 fields, thousands a tick at 1,000 robots) unpacked without a
    # generator: a third of a StateBatch's decoding.
    if n == 3:
        c0, c1, c2 = parts

        def conv3(v: Any) -> Any:
            if type(v) is list and len(v) == 3:
                a, b, c = v
                return c0(a), c1(b), c2(c)
            raise _fail(where, f"list of {n}", v)
        return conv3
    if n == 4:
        c0, c1, c2, c3 = parts

        def conv4(v: Any) -> Any:
            if type(v) is list and len(v) == 4:
                a, b, c, d = v
                return c0(a), c1(b), c2(c), c3(d)
            raise _fail(where, f"list of {n}", v)
        return conv4
    if n == 5:
        c0, c1, c2, c3, c4 = parts

        def conv5(v: Any) -> Any:
            if type(v) is list and len(v) == 5:
                a, b, c, d, e = v
                return c0(a), c1(b), c2(c), c3(d), c4(e)
            raise _fail(where, f"list of {n}", v)
        return conv5

    def conv(v: Any) -> Any:
        if type(v) is list and len(v) == n:
            return tuple(c(x) for c, x in zip(parts, v))
        raise _fail(where, f"list of {n}", v)
    return conv


def _list_converter(item_tp: Any, n: int, where: str, outer: int) -> Callable[[Any], Any]:
    item = converter(item_tp, f"{where}[i]", outer + 1)

    def conv(v: Any) -> Any:
        _check_sized(v, list, n, where)
        try:
            return [item(x) for x in v]
        except ProtocolError as exc:
            raise _indexed(exc, item, enumerate(v), f"{where}[i]", "[{}]") from None
    return conv


def _dict_converter(args: tuple[Any, Any], n: int, where: str, outer: int) -> Callable[[Any], Any]:
    key = converter(args[0], f"{where} key", outer + 1)
    value = converter(args[1], f"{where}[k]", outer + 1)

    def conv(v: Any) -> Any:
        _check_sized(v, dict, n, where)
        try:
            return {key(k): value(x) for k, x in v.items()}
        except ProtocolError as exc:
            for k in v:
                key(k)
            raise _indexed(exc, value, v.items(), f"{where}[k]", "[{!r}]") from None
    return conv


_KINDS = {list: ("list", "items"), dict: ("object", "keys"), str: ("str", "characters")}


def _check_sized(v: Any, kind: type, n: int, where: str) -> None:
    if type(v) is not kind:
        raise _fail(where, _KINDS[kind][0], v)
    if len(v) > n:
        raise ProtocolError(f"{where}: {len(v)} {_KINDS[kind][1]}, more than the limit of {n}")


def _indexed(first: ProtocolError, conv: Callable[[Any], Any], items: Any, placeholder: str,
             fmt: str) -> ProtocolError:
    """The error naming the item that failed: found by converting again, as the fast path keeps no index."""
    for at, x in items:
        try:
            conv(x)
        except ProtocolError as exc:
            return ProtocolError(str(exc).replace(placeholder, placeholder[:-3] + fmt.format(at), 1))
    return first
