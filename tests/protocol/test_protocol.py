"""Messages, keys and both transports (Zenoh on loopback and in-memory)."""
import dataclasses
import json
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
from hypothesis import given, settings, strategies as st

from protocol import bounds as m
from protocol.codec import decode, encode
from protocol.config import client_config, hub_config
from protocol.errors import MissionError, ProtocolError
from protocol.keys import Keys, robot_id_from_key
from protocol.messages import MESSAGE_TYPES, CameraFrame, MissionEnd, Plan, Record, RobotState, Tick, WorldInfo
from protocol.schemas import SCHEMA_DIR, schema_files, stale_files
from protocol.transport import MemoryBus, MemoryTransport, ZenohTransport

cells = st.tuples(st.integers(0, 10_000), st.integers(0, 10_000))

REPO = Path(__file__).resolve().parents[2]


@given(robot=st.integers(0, 10**6), pid=st.text(max_size=20), path=st.lists(cells, min_size=1, max_size=50),
       seq=st.integers(0, 2**40))
def test_plan_round_trip(robot, pid, path, seq):
    msg = Plan(robot=robot, plan_id=pid, path=path, goal=path[-1], seq=seq)
    assert decode(encode(msg), Plan) == msg


def test_binary_field_round_trip():
    png = bytes(range(256)) * 4  # includes NUL bytes: only the first NUL splits header from blob
    f = CameraFrame(width=4, height=3, fx=1.5, fy=1.5, cx=2, cy=1.5, north_m=-3, east_m=4, down_m=-20,
                    yaw_rad=0.3, time_s=1.0, png=png)
    assert decode(encode(f), CameraFrame) == f


@pytest.mark.parametrize("payload, needle", [
    (b"\xff\xfe garbage", "not JSON"),
    (b"[1,2]", "not a JSON object"),
    (b'{"type":"Tick","v":1,"k":1,"ticks":2,"plan_id":"a"}', "expected a Plan"),
    (b'{"type":"Plan","v":99,"robot":1}', "schema version"),
    (b'{"type":"Plan","v":1,"robot":1,"plan_id":"a","path":[[0,0]]}', "'goal' is missing"),
    (b'{"type":"Plan","v":1,"robot":true,"plan_id":"a","path":[[0,0]],"goal":[0,0]}', "Plan.robot"),
    (b'{"type":"Plan","v":1,"robot":1,"plan_id":"a","path":[[0,"x"]],"goal":[0,0]}', "Plan.path"),
])
def test_bad_payloads_are_one_line_errors(payload, needle):
    with pytest.raises(ProtocolError) as exc:
        decode(payload, Plan)
    assert needle in str(exc.value) and "\n" not in str(exc.value)


@given(st.binary(max_size=200))
def test_any_bytes_decode_or_raise_protocol_error(data):
    for cls in MESSAGE_TYPES.values():
        try:
            decode(data, cls)
        except ProtocolError:
            pass


def _plan(**kw) -> bytes:
    body = {"type": "Plan", "v": 1, "robot": 1, "plan_id": "a", "path": [[0, 0]], "goal": [0, 0], **kw}
    return json.dumps(body).encode()


@pytest.mark.parametrize("field, ok, bad", [
    ("robot", m.MAX_ROBOT_ID, m.MAX_ROBOT_ID + 1),
    ("robot", 0, -1),
    ("seq", m.MAX_COUNT, m.MAX_COUNT + 1),
    ("seq", 0, -1),
    ("goal", [m.MAX_GRID_SIDE - 1, 0], [m.MAX_GRID_SIDE, 0]),
    ("goal", [0, 0], [0, -1]),
    ("plan_id", "x" * m.MAX_TEXT_CHARS, "x" * (m.MAX_TEXT_CHARS + 1)),
    ("path", [[0, 0]] * m.MAX_PATH_CELLS, [[0, 0]] * (m.MAX_PATH_CELLS + 1)),
])
def test_limits_at_their_edges(field, ok, bad):
    assert decode(_plan(**{field: ok}), Plan)
    with pytest.raises(ProtocolError, match=f"Plan.{field}"):
        decode(_plan(**{field: bad}), Plan)


@pytest.mark.parametrize("payload, cls, needle", [
    (_plan(robot=True), Plan, "expected int"),
    (_plan(path=[[0, 0], [0, 1.0]]), Plan, r"Plan.path\[1\]"),
    (b'{"type":"Plan","v":1.0,"robot":1}', Plan, "schema version"),
    (b'{"type":"Plan","v":true,"robot":1}', Plan, "schema version"),
    (b'{"type":"MissionEnd","v":1,"completed":1}', MissionEnd, "expected bool"),
    (b'{"type":"Tick","v":1,"k":0,"ticks":1,"plan_id":"a"}', Tick, "Tick.k"),
    (b'{"type":"RobotState","v":1,"robot":1,"tick":1,"cell":[0,0],"status":"lost"}', RobotState, "one of"),
    (b'{"type":"WorldInfo","v":1,"width":8,"height":8,"cell_size_m":NaN,"home_lat":0,"home_lon":0,"home_alt_m":0}',
     WorldInfo, "NaN"),
    (b'{"type":"WorldInfo","v":1,"width":8,"height":8,"cell_size_m":1,"home_lat":0,"home_lon":0,"home_alt_m":1e999}',
     WorldInfo, "finite"),
    (b'{"type":"WorldInfo","v":1,"width":8,"height":8,"cell_size_m":0,"home_lat":0,"home_lon":0,"home_alt_m":0}',
     WorldInfo, "cell_size_m"),
    (b'{"type":"Plan","v":1,"x":' + b"[" * 100_000, Plan, "deeper than"),
    (_plan(x=json.loads("[" * 40 + "]" * 40)), Plan, "'x' nests deeper"),
    (b'{"type":"Record","v":1,"ticks":1,"collisions":0,"refused":[],"executed":{"07":[]},"truth":{}}', Record,
     "Record.executed key"),
    (_plan(plan_id="\ud800"), Plan, "surrogate"),
    ('{"type":"MissionEnd","v":1,"completed":true}'.encode("utf-16"), MissionEnd, "not UTF-8"),
    (b'{"type":"Plan","v":1,"robot":' + b"1" * 5000 + b"}", Plan, "not JSON"),
    (b" " * (m.MAX_MESSAGE_BYTES + 1), Plan, "over the limit"),
])
def test_malformed_values_are_refused(payload, cls, needle):
    with pytest.raises(ProtocolError, match=needle) as exc:
        decode(payload, cls)
    assert "\n" not in str(exc.value)


def _nested(levels: int):
    value = 0
    for _ in range(levels):
        value = [value]
    return value


def test_the_depth_limit_counts_the_whole_message():
    def record(**kw) -> bytes:
        return json.dumps({"type": "Record", "v": 1, "ticks": 0, "collisions": 0, "refused": [], "executed": {},
                           "truth": {}, **kw}).encode()
    # The message's own object is level 1 and truth level 2, so what truth holds may nest MAX_DEPTH - 2 more.
    assert decode(record(truth={"a": _nested(m.MAX_DEPTH - 2)}), Record)
    assert decode(record(new=_nested(m.MAX_DEPTH - 1)), Record)
    with pytest.raises(ProtocolError, match="Record.truth"):
        decode(record(truth={"a": _nested(m.MAX_DEPTH - 1)}), Record)
    with pytest.raises(ProtocolError, match="'new' nests deeper"):
        decode(record(new=_nested(m.MAX_DEPTH)), Record)


def test_camera_frame_limits_cover_head_and_image():
    f = CameraFrame(width=4, height=3, fx=1.5, fy=1.5, cx=2, cy=1.5, north_m=0, east_m=0, down_m=-20, yaw_rad=0,
                    time_s=0, png=b"\x89PNG")
    head = encode(f).partition(b"\0")[0]
    assert decode(head + b"\0" + b"x" * m.MAX_IMAGE_BYTES, CameraFrame).png == b"x" * m.MAX_IMAGE_BYTES
    with pytest.raises(ProtocolError, match="over the limit"):
        decode(head + b"\0" + b"x" * (m.MAX_IMAGE_BYTES + 1), CameraFrame)
    with pytest.raises(ProtocolError, match="CameraFrame.fx"):
        decode(encode(dataclasses.replace(f, fx=0.0)), CameraFrame)


def test_shipped_schemas_are_what_the_messages_generate():
    assert stale_files() == [], "run: python -m protocol.schemas --write"
    assert sorted(p.name for p in SCHEMA_DIR.glob("*.schema.json")) == sorted(schema_files())


def test_shipped_schemas_accept_every_message_and_refuse_a_bad_one():
    jsonschema = pytest.importorskip("jsonschema")
    from message_strategies import TYPES, messages

    shipped = {cls: json.loads((SCHEMA_DIR / f"{cls.__name__}.schema.json").read_text()) for cls in TYPES}
    for schema in shipped.values():
        jsonschema.Draft202012Validator.check_schema(schema)
    validators = {cls: jsonschema.Draft202012Validator(schema) for cls, schema in shipped.items()}

    @settings(max_examples=25, deadline=None, derandomize=True)
    @given(st.data())
    def check(data):
        for cls in TYPES:
            head = encode(data.draw(messages(cls))).partition(b"\0")[0]  # a CameraFrame's schema covers its JSON
            validators[cls].validate(json.loads(head))

    check()
    for bad in (_plan(robot=-1), _plan(goal=[0, m.MAX_GRID_SIDE]), _plan(path=[[0, 0, 0]]), _plan(v=2)):
        assert not validators[Plan].is_valid(json.loads(bad))


def test_keys_and_ids():
    k = Keys("f1")
    assert k.plan(7) == "uavr/f1/robot/7/plan"
    assert robot_id_from_key(k.state(12)) == 12
    assert robot_id_from_key(k.alive_robot(3)) == 3
    assert robot_id_from_key(k.tick) is None
    for bad in ("²", "007", "1" * 5000, "-1", "1.0", ""):
        assert robot_id_from_key(f"uavr/f1/robot/{bad}/state") is None
    with pytest.raises(Exception):
        Keys("bad/fleet")


def _exercise(hub, client):
    """The same checks for any Transport pair: pub/sub, deferred queries, liveliness."""
    got, alive = [], []
    ev = threading.Event()
    hub.subscribe("t/robot/*/state", lambda k, p: (got.append((k, p)), ev.set()))
    hub.watch_alive("t/alive/robot/*", lambda k, a: alive.append((k, a)))
    pending = []

    def serve(q):  # answer only once two queries are in: like the world's tick batch
        pending.append(q)
        if len(pending) == 2:
            for p in pending:
                p.reply(b"ok:" + p.payload)

    hub.serve("t/world/move", serve)
    time.sleep(0.2)
    tok = client.announce("t/alive/robot/4")
    client.put("t/robot/4/state", b"s")
    assert ev.wait(5)
    a = client.request_start("t/world/move", b"1", 5)
    b = client.request_start("t/world/move", b"2", 5)
    assert a.wait() == [b"ok:1"] and b.wait() == [b"ok:2"]
    tok.close()
    deadline = time.time() + 5
    while ("t/alive/robot/4", False) not in alive and time.time() < deadline:
        time.sleep(0.02)
    assert got == [("t/robot/4/state", b"s")]
    assert alive[0] == ("t/alive/robot/4", True) and alive[-1] == ("t/alive/robot/4", False)


def test_memory_transport():
    bus = MemoryBus()
    _exercise(MemoryTransport(bus), MemoryTransport(bus))


def test_zenoh_transport(zenoh_endpoint):
    with ZenohTransport(hub_config([zenoh_endpoint]), "hub") as hub, \
         ZenohTransport(client_config([zenoh_endpoint]), "client") as client:
        _exercise(hub, client)


def test_zenoh_unreachable_hub_is_a_one_line_error():
    t0 = time.monotonic()
    with pytest.raises(MissionError, match="cannot open zenoh session"):
        ZenohTransport(client_config(["tcp/127.0.0.1:9"], timeout_ms=300), "robot")
    assert time.monotonic() - t0 < 10


def test_zenoh_bad_config_is_a_one_line_error():
    with pytest.raises(MissionError, match="zenoh config rejected"):
        ZenohTransport('{"mode": "nonsense"}')


def test_a_command_leaves_its_heap_frozen_for_the_exit_and_a_caller_untouched(monkeypatch):
    """A command run as the process itself skips the collections at its exit (0.3-0.4 s for the UAV's
    libraries); called with an argument list, by a test or another command, it leaves the heap alone."""
    import gc

    from protocol.process import command_main, one_command

    def build(argv):
        return one_command("probe", "a command that does nothing", lambda p: p.add_argument("--n", type=int),
                           lambda a: a.n)(argv)

    term = signal.getsignal(signal.SIGTERM)     # command_main installs its own
    gc.unfreeze()
    try:
        assert command_main(build, ["--n", "3"]) == 3 and gc.get_freeze_count() == 0
        monkeypatch.setattr(sys, "argv", ["probe", "--n", "4"])
        assert command_main(build) == 4 and gc.get_freeze_count() > 0
    finally:
        gc.unfreeze()
        signal.signal(signal.SIGTERM, term)


@pytest.mark.process
def test_warning_lines_are_throttled_printable_and_their_tail_said_at_exit():
    """A flood of bad input is one line a second; what a stranger sent is shown escaped, on one line;
    the lines held back after the last one shown are counted at the process's exit (they were lost)."""
    code = ("from protocol.log import Throttled\n"
            "w = Throttled('probe')\n"
            "w('bad \\x1b[31mred\\x1b[0m\\nsecond line')\n"
            "for i in range(99): w(f'bad {i}')\n")
    run = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=60)
    lines = run.stderr.splitlines()
    assert run.returncode == 0 and len(lines) == 2, run.stderr
    assert lines[0] == r"warning: probe: bad \x1b[31mred\x1b[0m\nsecond line"
    assert lines[1] == "warning: probe: 99 more held back (100 in all)"


def test_refusals_name_the_real_problem():
    """An object without a type used to be 'got type None'; an over-long ids key 'names no robot ids'."""
    from protocol.errors import UavRobotsError
    from protocol.keys import ids_of_move_key

    with pytest.raises(ProtocolError, match="an object without a 'type'"):
        decode(b"{}", Tick)
    keys = Keys("t")
    with pytest.raises(UavRobotsError, match="its robot ids are 4800 characters, more than 4096"):
        ids_of_move_key(keys, keys.move + "/" + "1," * 2400)
