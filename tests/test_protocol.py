"""Messages, keys and both transports (Zenoh on loopback and in-memory)."""
import threading
import time

import pytest
from hypothesis import given, strategies as st

from protocol.config import client_config, hub_config
from protocol.errors import MissionError, ProtocolError
from protocol.keys import Keys, robot_id_from_key
from protocol.messages import (MESSAGE_TYPES, CameraFrame, Plan, decode, encode)
from protocol.transport import MemoryBus, MemoryTransport, ZenohTransport

cells = st.tuples(st.integers(0, 10_000), st.integers(0, 10_000))


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


def test_keys_and_ids():
    k = Keys("f1")
    assert k.plan(7) == "uavr/f1/robot/7/plan"
    assert robot_id_from_key(k.state(12)) == 12
    assert robot_id_from_key(k.alive_robot(3)) == 3
    assert robot_id_from_key(k.tick) is None
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
