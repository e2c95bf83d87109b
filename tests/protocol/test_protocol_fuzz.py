"""Property-based fuzzing of every decoder of outside input: messages, maps, scenarios, plan files.

Each decoder either returns a valid value or raises its documented error
(ProtocolError, MapError, PlanningError) with one line: never another exception,
never a hang. Runs are derandomized so CI sees the same inputs every time.
"""
import json
import time
from functools import cache

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from message_strategies import TYPES, messages
from protocol.codec import decode, encode
from protocol.errors import MapError, PlanningError, ProtocolError
from protocol.mapfile import parse_map_text, read_scen
from protocol.schemas import message_schema
from uav_agent.planning.plan_io import plan_from_dict, read_plan

try:
    import jsonschema
except ImportError:  # accepted messages are checked against their schemas where jsonschema is installed
    jsonschema = None

FUZZ = settings(max_examples=150, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow])
SLOW_S = 2.0  # a decode that takes this long on a few kB is a hang in the making

HOSTILE = ["NaN", "Infinity", "-Infinity", "1e999", "-1e999", "-1", "-4611686018427387904", "1" * 5000,
           str(2**64), str(2**53), "0.5", "-0.0", "true", "false", "null", '""', '"x"', '"' + "y" * 5000 + '"',
           '"\\ud800"', "[]", "{}", "[0]", "[0,0,0]", "[-1,-1]", "[1e400,1]", "[true,1]", "[1.0,2.0]",
           '{"a":1}', '[[0,0],[0,-1]]', '["0",1]']


def nesting_bomb(depth: int, kind: str) -> str:
    return {"array": "[" * depth + "]" * depth, "open": "[" * depth,
            "object": '{"a":' * depth + "1" + "}" * depth, "mixed": '[{"a":' * depth}[kind]


bombs = st.builds(nesting_bomb, st.sampled_from([31, 33, 200, 999, 1000, 5000, 100_000]),
                  st.sampled_from(["array", "open", "object", "mixed"]))
hostile_values = st.sampled_from(HOSTILE) | bombs | st.integers().map(str) | st.floats().map(
    lambda f: json.dumps(f))


def _split(data: bytes) -> tuple[bytes, bytes]:
    head, sep, blob = data.partition(b"\0")
    return head, sep + blob


@st.composite
def mutated(draw, cls):
    """A valid encoding of `cls`, then one hostile edit of its bytes or of its JSON."""
    data = encode(draw(messages(cls)))
    head, tail = _split(data)
    body = json.loads(head)
    kind = draw(st.sampled_from(["flip", "truncate", "splice", "delete", "retype", "retype-inner", "duplicate",
                                 "encoding", "append"]))
    if kind == "flip":
        b = bytearray(data)
        for at in draw(st.lists(st.integers(0, len(b) - 1), min_size=1, max_size=4)):
            b[at] ^= 1 << draw(st.integers(0, 7))
        return bytes(b)
    if kind == "truncate":
        return data[:draw(st.integers(0, len(data)))]
    if kind == "splice":
        at = draw(st.integers(0, len(head)))
        return head[:at] + draw(st.binary(min_size=1, max_size=16)) + head[at:] + tail
    key = draw(st.sampled_from(sorted(body)))
    if kind == "delete":
        del body[key]
        return json.dumps(body).encode() + tail
    if kind == "encoding":
        return head.decode().encode(draw(st.sampled_from(["utf-16", "utf-16-be", "utf-32", "utf-8-sig"]))) + tail
    value = draw(hostile_values)
    if kind == "retype":
        body[key] = "\x01HOSTILE\x01"
        return json.dumps(body).replace('"\\u0001HOSTILE\\u0001"', value).encode() + tail
    if kind == "retype-inner":  # one more item deep inside: a path's first cell, a cell's first coordinate
        text = json.dumps(body)
        at = draw(st.sampled_from([i for i, c in enumerate(text) if c in "[,"]))
        return (text[:at + 1] + value + "," + text[at + 1:]).encode() + tail
    if kind == "duplicate":  # JSON lets the last of two equal keys win
        return (head[:-1] + b',"' + key.encode() + b'":' + value.encode() + b"}") + tail
    return head + draw(st.sampled_from([b" ", b"x", b",", b"}", b"]", b"\x00"])) + tail


def decodes_or_refuses(data: bytes, cls) -> None:
    t0 = time.perf_counter()
    try:
        msg = decode(data, cls)
    except ProtocolError as exc:
        text = str(exc)
        assert text and "\n" not in text and len(text) < 400, text
        return
    finally:
        assert time.perf_counter() - t0 < SLOW_S
    assert type(msg) is cls
    # What was accepted is a valid message: it survives its own round trip and fits its schema.
    again = encode(msg)
    assert decode(again, cls) == msg
    if jsonschema is not None:
        _validator(cls).validate(json.loads(_split(again)[0]))


@cache
def _validator(cls):
    return jsonschema.Draft202012Validator(message_schema(cls))


ids = [c.__name__ for c in TYPES]


@pytest.mark.slow
@pytest.mark.parametrize("cls", TYPES, ids=ids)
@FUZZ
@given(data=st.data())
def test_round_trip(cls, data):
    msg = data.draw(messages(cls))
    wire = encode(msg)
    assert decode(wire, cls) == msg
    assert encode(decode(wire, cls)) == wire


@pytest.mark.slow
@pytest.mark.parametrize("cls", TYPES, ids=ids)
@FUZZ
@given(data=st.binary(max_size=400))
def test_random_bytes(cls, data):
    decodes_or_refuses(data, cls)


@pytest.mark.slow
@pytest.mark.parametrize("cls", TYPES, ids=ids)
@settings(FUZZ, max_examples=300)
@given(data=st.data())
def test_mutated_encodings(cls, data):
    decodes_or_refuses(data.draw(mutated(cls)), cls)


@pytest.mark.slow
@pytest.mark.parametrize("cls", TYPES, ids=ids)
@FUZZ
@given(data=st.data())
def test_another_types_encoding(cls, data):
    other = data.draw(st.sampled_from(TYPES))
    decodes_or_refuses(encode(data.draw(messages(other))), cls)


# ------------------------------------------------------------------ maps, scenarios, plan files

MAP_TEXT = "type octile\nheight 3\nwidth 4\nmap\n.@..\n..G.\n@@.T\n"
map_lines = st.sampled_from(["type octile", "height 3", "width 4", "height -1", "width 0", "height 99999999999999",
                             "width x", "map", "MAP", ".@..", "....", "...", ".....", "", " ", "\t", "a b c",
                             "height ٣", "width 4\r", "..G.\r"])


@st.composite
def map_texts(draw):
    if draw(st.booleans()):
        return draw(st.text(max_size=200))
    lines = MAP_TEXT.splitlines()
    for _ in range(draw(st.integers(1, 4))):
        at = draw(st.integers(0, len(lines)))
        op = draw(st.sampled_from(["insert", "replace", "delete"]))
        if op == "insert" or not lines:
            lines.insert(at, draw(map_lines | st.text(max_size=12)))
        elif op == "replace":
            lines[min(at, len(lines) - 1)] = draw(map_lines | st.text(max_size=12))
        else:
            del lines[min(at, len(lines) - 1)]
    return "\n".join(lines) + draw(st.sampled_from(["", "\n"]))


@FUZZ
@given(text=map_texts())
def test_map_text(text):
    try:
        free = parse_map_text(text, "fuzz.map")
    except MapError as exc:
        assert "\n" not in str(exc)
        return
    assert free.dtype == bool and free.ndim == 2 and min(free.shape) >= 1


SCEN_LINE = "0\tm.map\t4\t3\t0\t0\t2\t1\t2.5"
scen_fields = st.sampled_from(["0", "-1", "-7", "3", "99", "x", "", "1e3", "nan", "inf", "2.5", "٣", str(2**70)])


@st.composite
def scen_bytes(draw):
    if draw(st.booleans()):
        return draw(st.binary(max_size=200))
    lines = ["version 1"]
    for _ in range(draw(st.integers(1, 3))):
        parts = SCEN_LINE.split("\t")
        for at in draw(st.lists(st.sampled_from([4, 5, 6, 7, 8, 0, 1, 2, 3]), max_size=2)):
            parts[at] = draw(scen_fields | st.text(max_size=6))
        del parts[draw(st.sampled_from([9, 9, 9, 8, 7])):]
        lines.append(draw(st.sampled_from(["\t", " "])).join(parts))
    return "\n".join(lines).encode("utf-8", "surrogatepass")


@pytest.fixture(scope="module")
def fuzz_dir(tmp_path_factory):
    return tmp_path_factory.mktemp("fuzz")


@settings(FUZZ, max_examples=400)
@given(data=scen_bytes(), agents=st.none() | st.integers(0, 5), with_map=st.booleans())
def test_scenario_file(fuzz_dir, data, agents, with_map):
    path = fuzz_dir / "f.scen"
    path.write_bytes(data)
    free = parse_map_text(MAP_TEXT) if with_map else None
    try:
        out = read_scen(path, free, agents)
    except MapError as exc:
        assert "\n" not in str(exc)
        return
    assert agents is None or len(out) == agents
    for a in out:
        assert min(a.start + a.goal) >= 0
        if free is not None:
            assert free[a.start[1], a.start[0]] and free[a.goal[1], a.goal[0]]


def _plan_dict() -> dict:
    return {"format": "uav-robots-plan/1", "map": {"name": "m", "width": 4, "height": 3,
                                                  "rows": ["....", ".@..", "...."]},
            "connectivity": 4, "planner": "x", "metrics": {"makespan": 2}, "timings": {"total": 0.1},
            "robots": [{"id": 0, "start": [0, 0], "goal": [2, 0], "cost": 2, "path": [[0, 0], [1, 0], [2, 0]]},
                       {"id": 7, "start": [0, 2], "goal": [0, 1], "cost": 1, "path": [[0, 2], [0, 1]]}]}


def _mutate_json(draw, value, depth=0):
    """One hostile edit somewhere inside a JSON value."""
    if isinstance(value, dict) and value and depth < 4 and draw(st.booleans()):
        key = draw(st.sampled_from(sorted(value)))
        op = draw(st.sampled_from(["into", "delete", "replace"]))
        if op == "delete":
            return {k: v for k, v in value.items() if k != key}
        new = _mutate_json(draw, value[key], depth + 1) if op == "into" else json.loads(draw(plain_hostile))
        return {**value, key: new}
    if isinstance(value, list) and value and depth < 4 and draw(st.booleans()):
        at = draw(st.integers(0, len(value) - 1))
        return value[:at] + [_mutate_json(draw, value[at], depth + 1)] + value[at + 1:]
    return json.loads(draw(plain_hostile))


plain_hostile = st.sampled_from([h for h in HOSTILE if h not in ("NaN", "Infinity", "-Infinity") and len(h) < 100]
                                + ["[[0,0]]", '["...."]', '[""]', "[4]", "4", "8", '{"rows":[]}', '[[0,0],[9,9]]',
                                   '{"id":0}', '[{"id":0,"start":[0,0],"goal":[0,0],"path":[[0,0]]}]'])


@FUZZ
@given(data=st.data())
def test_plan_dict(data):
    d = _mutate_json(data.draw, _plan_dict()) if data.draw(st.booleans()) else data.draw(
        st.recursive(st.none() | st.integers() | st.text(max_size=6), lambda c: st.lists(c, max_size=3)
                     | st.dictionaries(st.text(max_size=6), c, max_size=3), max_leaves=12))
    try:
        plan = plan_from_dict(d, "fuzz")
    except PlanningError as exc:
        assert "\n" not in str(exc)
        return
    assert len(plan.ids) == len(plan.paths) == len(plan.starts) >= 1


@FUZZ
@given(data=st.data())
def test_plan_file(fuzz_dir, data):
    choice = data.draw(st.sampled_from(["bytes", "mutated", "bomb"]))
    if choice == "bytes":
        raw = data.draw(st.binary(max_size=300))
    elif choice == "mutated":
        raw = json.dumps(_mutate_json(data.draw, _plan_dict())).encode()
    else:
        raw = json.dumps(_plan_dict()).replace('"metrics": {', '"metrics": {"x": ' + data.draw(bombs) + ",").encode()
    path = fuzz_dir / "f.plan.json"
    path.write_bytes(raw)
    try:
        plan = read_plan(path)
    except PlanningError as exc:
        assert "\n" not in str(exc)
        return
    assert isinstance(plan.free, np.ndarray)
