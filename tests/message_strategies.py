"""Hypothesis strategies for valid messages of every type, read off the bounded field types.

Sizes are capped well below the protocol's limits so examples stay fast; the limits
themselves are tested at their exact edges in tests/protocol/test_protocol.py.
"""
from functools import cache
from typing import Any, Literal, get_args, get_origin

from hypothesis import strategies as st

from protocol.bounds import MaxLen, Pattern, Range, bound, unwrap
from protocol.messages import MESSAGE_TYPES, Message, wire_fields

MAX_EXAMPLE_ITEMS = 12


@cache  # building strategies costs more than drawing from them
def json_values(depth: int = 2) -> st.SearchStrategy[Any]:
    """Free-form JSON values (what an `Any` field holds), nested at most `depth` levels."""
    leaf = (st.none() | st.booleans() | st.integers(-2**63, 2**63) | st.text(max_size=12)
            | st.floats(allow_nan=False, allow_infinity=False))
    if depth == 0:
        return leaf
    inner = json_values(depth - 1)
    return leaf | st.lists(inner, max_size=3) | st.dictionaries(st.text(max_size=8), inner, max_size=3)


def for_type(tp: Any) -> st.SearchStrategy[Any]:
    base, meta = unwrap(tp)
    origin = get_origin(base)
    if base is Any:
        return json_values()
    if base is bool:
        return st.booleans()
    if base is int:
        r = bound(meta, Range)
        return st.integers(r.lo, r.hi)
    if base is float:
        r = bound(meta, Range)
        return st.floats(r.lo, r.hi, exclude_min=r.open_lo, allow_nan=False, allow_infinity=False)
    if base is bytes:
        return st.binary(max_size=64)
    if base is str:
        n, pattern = bound(meta, MaxLen).n, bound(meta, Pattern)
        if pattern is not None:
            return st.from_regex(pattern.regex, fullmatch=True).filter(lambda s: len(s) <= n)
        return st.text(max_size=min(n, 24))
    if origin is Literal:
        return st.sampled_from(get_args(base))
    if origin is tuple:
        return st.tuples(*(for_type(a) for a in get_args(base)))
    if origin is list:
        return st.lists(for_type(get_args(base)[0]), max_size=MAX_EXAMPLE_ITEMS)
    if origin is dict:
        key, value = get_args(base)
        return st.dictionaries(for_type(key), for_type(value), max_size=4)
    raise TypeError(f"no strategy for {tp}")


@cache
def messages(cls: type[Message]) -> st.SearchStrategy[Message]:
    return st.builds(cls, **{f.name: for_type(f.type) for f in wire_fields(cls)})


TYPES = sorted(MESSAGE_TYPES.values(), key=lambda c: c.__name__)
