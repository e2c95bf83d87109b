"""Every documented limit is checked up front, in one line, and every bad input to the parsers of maps,
scenarios and fleet.json is one clean error, found by fuzzing (issue 29, item 12); every message type
has a byte limit derived from its fields, checked before parsing and counted (item 13)."""
from __future__ import annotations

import dataclasses
import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from protocol.bounds import MARGIN_BYTES, MAX_MESSAGE_BYTES, MaxLen, Pattern, Range, bound, unwrap
from protocol.codec import decode, encode, json_limit
from protocol.errors import MapError, ProtocolError, UavRobotsError
from protocol.mapfile import MAX_HEADER_BYTES, read_map, read_scen
from protocol.messages import MESSAGE_TYPES, Plan, RobotState, wire_fields
from scenarios.limits import MAX_FLEET, MAX_FLOOR_CELLS, check_floor
from scenarios.maps import NAMED, resolve_map
from uav_robots.secure.fleet import MANIFEST, new_fleet, read_fleet_dir

REPO = Path(__file__).resolve().parents[2]
FUZZ = settings(max_examples=200, deadline=None, derandomize=True,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])


def _command(argv: list[str], timeout: float = 60) -> subprocess.CompletedProcess:
    """`uav-robots ...` in its own process group: killed whole if it started a mission after all."""
    proc = subprocess.Popen([sys.executable, "-m", "uav_robots", *argv], cwd=REPO, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        out, err = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        out, err = proc.communicate()
        pytest.fail(f"uav-robots {' '.join(argv)[:120]}: still running after {timeout:g} s: the limit was not "
                    f"checked up front ({err[-300:]!r})")
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    return subprocess.CompletedProcess(argv, proc.returncode, out, err)


def _one_line(run: subprocess.CompletedProcess, *words: str) -> str:
    lines = run.stderr.strip().splitlines()
    assert run.returncode == 2, (run.returncode, run.stdout[-300:], run.stderr[-500:])
    assert run.stdout == "", "a process was started or a header printed before the check"
    assert len(lines) == 1 and lines[0].startswith("error: "), lines[-5:]
    for w in words:
        assert w in lines[0], (w, lines[0])
    return lines[0]


@pytest.fixture(scope="module")
def huge_map(tmp_path_factory) -> Path:
    """The issue's 4200x4200 floor (17.6 MB), read whole it took 4.2 GB and nothing came within 900 s."""
    path = tmp_path_factory.mktemp("maps") / "huge.map"
    row = b"." * 4200 + b"\n"
    with path.open("wb") as f:
        f.write(b"type octile\nheight 4200\nwidth 4200\nmap\n")
        f.writelines(row for _ in range(4200))
    return path


# ------------------------------------------------------------------ up front, in one line

@pytest.mark.process
def test_a_fleet_larger_than_the_marker_dictionary_is_refused_before_anything_starts():
    # It was refused only after every process had started, as "no answer from the world's camera within 30 s".
    # warehouse-450 has room for them: nothing else would stop these runs.
    _one_line(_command(["run", "--robots", str(MAX_FLEET + 1), "--map", "warehouse-450"]), f"--robots {MAX_FLEET + 1}",
              "DICT_4X4_1000")
    _one_line(_command(["world", "--robots", "2000", "--map", "warehouse-450", "--mavlink", "none"]),
              "at most 1000 robots", "marker")


def test_the_fleet_limit_is_the_robot_markers_dictionary_and_landmarks_have_their_own():
    import cv2

    from scenarios.landmarks import LANDMARK_FAMILY
    from scenarios.limits import MARKER_FAMILY
    from sim_world.camera import ARUCO_DICTIONARY, MARKER_IDS
    from uav_agent.perception import markers

    robots = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, MARKER_FAMILY))
    assert ARUCO_DICTIONARY == markers.ARUCO_DICTIONARY == getattr(cv2.aruco, MARKER_FAMILY)
    assert MAX_FLEET == MARKER_IDS == len(robots.bytesList)
    assert LANDMARK_FAMILY != MARKER_FAMILY   # landmark ids never read as robots


@pytest.mark.process
def test_a_floor_larger_than_a_mission_covers_is_refused_from_its_header(huge_map):
    words = ("4200x4200 floor", f"{MAX_FLOOR_CELLS:,}")
    _one_line(_command(["run", "--map", str(huge_map)]), *words)
    _one_line(_command(["world", "--map", str(huge_map), "--mavlink", "none"]), *words)
    _one_line(_command(["run", "--map", "warehouse:blocks_x=200,blocks_y=500"]), "a mission's")
    with pytest.raises(MapError, match="more than 16,777,216"):   # the planners' own limit, 4096x4096
        read_map(huge_map)


def test_a_floor_at_the_limit_is_a_mission_floor():
    side = int(MAX_FLOOR_CELLS ** 0.5)
    check_floor(side, side, "edge")
    with pytest.raises(MapError, match="more than a mission's"):
        check_floor(side + 1, side, "edge")
    for name in NAMED:
        resolve_map(name, 0, check_floor)


def test_a_huge_header_is_refused_without_reading_the_rows(tmp_path):
    """The header is checked before a row is read: a file that claims 100000x100000 is refused at once,
    and one whose rows go on past the header's size is read only as far as the header says."""
    claims = tmp_path / "claims.map"
    claims.write_bytes(b"type octile\nheight 100000\nwidth 100000\nmap\n" + b"." * (MAX_HEADER_BYTES * 2))
    with pytest.raises(MapError, match="exceeds the protocol's 16384 cells per side"):
        read_map(claims)
    long = tmp_path / "long.map"
    long.write_bytes(b"type octile\nheight 2\nwidth 3\nmap\n...\n.@.\n" + b"garbage\n" * MAX_HEADER_BYTES)
    assert read_map(long).tolist() == [[True, True, True], [True, False, True]]
    nomap = tmp_path / "nomap.map"
    nomap.write_bytes(b"x" * (MAX_HEADER_BYTES + 10))
    with pytest.raises(MapError, match="no 'map' line"):
        read_map(nomap)


@pytest.mark.parametrize("argv, words", [
    (["run", "--map", "random:width=10,height=10,seed=-1"], ["seed must be a whole number"]),
    (["run", "--map", "x" * 300], ["unknown map"]),
    (["run", "--map", "x" * 300 + ".map"], ["File name too long"]),
    (["run", "--map", "warehouse:blocks_x=2.5,blocks_y=3"], ["not a whole number"]),
    (["run", "--map", "warehouse:blocks_x=3,blocks_y=3,width=9"], ["a warehouse takes"]),
    (["world", "--seed", "-1", "--mavlink", "none"], ["seed must be a whole number"]),
])
@pytest.mark.process
def test_bad_map_specs_are_one_line(argv, words):
    _one_line(_command(argv), *words)


@pytest.mark.process
def test_out_under_a_file_is_one_line(tmp_path):
    f = tmp_path / "report"
    f.write_text("x")
    _one_line(_command(["run", "--out", str(f / "sub")]), "is a file, not a directory")
    _one_line(_command(["run", "--out", str(tmp_path / ("y" * 300))]), "File name too long")


# ------------------------------------------------------------------ fuzz: every bad input one clean line

def _clean(exc: Exception) -> None:
    assert "\n" not in str(exc) and len(str(exc)) < 1000, str(exc)[:300]


NAMES = ["warehouse", "random", "Warehouse", "", "warehouse-small", "warehouse-450", "room-64-64-8", "..", "/",
         "/dev/null", "a\nb", "a\x1b[2Jb", "x" * 255, "x" * 256, "x" * 300 + ".map", "a\0b", "a\0b.map", "é" * 130]
PARAMS = ["blocks_x", "blocks_y", "shelf_w", "shelf_h", "aisle", "dock", "margin", "width", "height", "density",
          "seed", "junk", ""]
VALUES = ["-1", "0", "1", "2", "3", "17", "0.5", "2.5", "1e300", "-1e300", "nan", "inf", "-0", "", "x",
          str(2**70), "99999999999", "0x10", "٣", "1_0", " 3", "3 ", "4294967296", "4294967295"]


@st.composite
def map_specs(draw):
    choice = draw(st.sampled_from(["text", "name", "generator", "generator", "generator"]))
    if choice == "text":
        return draw(st.text(max_size=300))
    if choice == "name":
        return draw(st.sampled_from(NAMES)) + draw(st.sampled_from(["", ".map", "/x.map", ":"]))
    parts = [f"{draw(st.sampled_from(PARAMS))}{draw(st.sampled_from(['=', '', '==']))}{draw(st.sampled_from(VALUES))}"
             for _ in range(draw(st.integers(0, 5)))]
    if draw(st.booleans()):   # a valid base that the parts then change
        parts = ["blocks_x=3", "blocks_y=2"] + parts if draw(st.booleans()) else ["width=9", "height=7"] + parts
    return f"{draw(st.sampled_from(['warehouse', 'random']))}:{','.join(parts)}"


@FUZZ
@given(spec=map_specs(), seed=st.integers(-2**40, 2**40) | st.sampled_from([0, 1, 2**32 - 1, 2**32]),
       mission=st.booleans())
def test_fuzz_map_specs(spec, seed, mission):
    try:
        name, free = resolve_map(spec, seed, check_floor) if mission else resolve_map(spec, seed)
    except MapError as exc:
        _clean(exc)
        return
    assert isinstance(name, str) and free.dtype == bool and free.ndim == 2 and free.size >= 1
    assert seed >= 0


MAP_HEAD = "type octile\nheight {h}\nwidth {w}\nmap\n"
HEAD_VALUES = ["3", "4", "0", "-3", "4200", "100000", str(2**64), "x", "٣", "1e3", "3.0", ""]


@st.composite
def map_files(draw):
    """Map files around a valid one: numbers in the header, rows, sizes past the header's read-ahead."""
    if draw(st.integers(0, 5)) == 0:
        return draw(st.binary(max_size=300))
    w, h = draw(st.sampled_from(HEAD_VALUES)), draw(st.sampled_from(HEAD_VALUES))
    rows = draw(st.sampled_from([3, 4, 300]))
    width = draw(st.sampled_from([4, 3, 300]))
    body = "\n".join(draw(st.sampled_from([".", "@", "G", "T"])) * width for _ in range(rows))
    text = MAP_HEAD.format(h=h, w=w) + body
    if draw(st.booleans()):   # one hostile edit anywhere
        at = draw(st.integers(0, len(text)))
        text = text[:at] + draw(st.sampled_from(["\n", "\0", "map\n", "height 9\n", "\r\n", "x", "é", "\x0c"])) + text[at:]
    return text.encode("utf-8")


@pytest.fixture(scope="module")
def fuzz_dir(tmp_path_factory):
    return tmp_path_factory.mktemp("fuzz-limits")


@FUZZ
@given(data=map_files(), mission=st.booleans())
def test_fuzz_map_files(fuzz_dir, data, mission):
    path = fuzz_dir / "f.map"
    path.write_bytes(data)
    try:
        free = read_map(path, check_floor) if mission else read_map(path)
    except MapError as exc:
        _clean(exc)
        return
    assert free.dtype == bool and free.ndim == 2 and min(free.shape) >= 1


@FUZZ
@given(name=st.sampled_from(NAMES) | st.text(max_size=300), reader=st.sampled_from(["map", "scen"]))
def test_fuzz_file_names(name, reader):
    """Names the system cannot take (too long, a NUL byte, a directory) are a line, as a missing file is."""
    try:
        read_map(name) if reader == "map" else read_scen(name)
    except MapError as exc:
        _clean(exc)


def _manifest(tmp_path: Path) -> dict:
    """What `secure init` writes for 3 robots in 2 processes, beside (empty) files for every identity."""
    fleet = new_fleet("fz", 3, [[0], [1, 2]], ["127.0.0.1"], 7447, tmp_path)
    for who in fleet.identities():
        for ext in ("pem", "key", "json5"):
            (tmp_path / f"{who.name}.{ext}").touch()
    return dataclasses.asdict(fleet)


HOSTILE = [None, True, False, 0, -1, 1, 3, 2**70, 1.5, float("1e300"), "", "x", "fz", "a b", "\0", "x" * 300, [],
           {}, [0], [[0]], [[0, 1, 2]], [[-1]], [[0], [0]], [[]], [["0"]], [[True]], ["127.0.0.1"], [""], ["a/b"],
           [1], {"a": 1}, 65535, 65536, 70000]


def _mutate(draw, value, depth=0):
    if isinstance(value, dict) and value and depth < 3 and draw(st.booleans()):
        key = draw(st.sampled_from(sorted(value)))
        op = draw(st.sampled_from(["into", "delete", "replace", "add"]))
        if op == "delete":
            return {k: v for k, v in value.items() if k != key}
        if op == "add":
            return {**value, draw(st.sampled_from(["extra", "v", key])): draw(st.sampled_from(HOSTILE))}
        return {**value, key: _mutate(draw, value[key], depth + 1) if op == "into" else draw(st.sampled_from(HOSTILE))}
    if isinstance(value, list) and value and depth < 3 and draw(st.booleans()):
        at = draw(st.integers(0, len(value) - 1))
        return value[:at] + [_mutate(draw, value[at], depth + 1)] + value[at + 1:]
    return draw(st.sampled_from(HOSTILE))


@pytest.fixture(scope="module")
def secure_dir(tmp_path_factory):
    d = tmp_path_factory.mktemp("secure")
    return d, _manifest(d)


@FUZZ
@given(data=st.data())
def test_fuzz_fleet_manifest(secure_dir, data):
    d, good = secure_dir
    choice = data.draw(st.sampled_from(["mutated", "mutated", "mutated", "bytes", "bomb", "json"]))
    if choice == "mutated":
        raw = json.dumps(_mutate(data.draw, good)).encode()
    elif choice == "bytes":
        raw = data.draw(st.binary(max_size=200))
    elif choice == "bomb":
        raw = ("[" * 100_000 + "]" * 100_000).encode()
    else:
        raw = json.dumps(data.draw(st.recursive(st.none() | st.integers() | st.text(max_size=6),
                                                lambda c: st.lists(c, max_size=3) | st.dictionaries(
                                                    st.text(max_size=8), c, max_size=3), max_leaves=10))).encode()
    (d / MANIFEST).write_bytes(raw)
    try:
        fleet = read_fleet_dir(d)
    except UavRobotsError as exc:
        _clean(exc)
        return
    assert 1 <= fleet.robots and sorted(r for g in fleet.groups for r in g) == list(range(fleet.robots))
    assert all(w.name for w in fleet.identities())


def test_a_manifest_secure_init_writes_is_read_back(tmp_path):
    good = _manifest(tmp_path)
    (tmp_path / MANIFEST).write_text(json.dumps(good, indent=1))
    fleet = read_fleet_dir(tmp_path)
    assert fleet.robots == 3 and fleet.groups == [[0], [1, 2]] and fleet.files_at == str(tmp_path)


@pytest.mark.parametrize("change, words", [
    ({"robots": "3"}, "'robots' is not a JSON integer"),
    ({"robots": True}, "'robots' is not a JSON integer"),
    ({"groups": [[0], [1]]}, "each robot 0..2 once"),
    ({"groups": [[0], ["1", 2]]}, "lists of robot ids"),
    ({"fleet": "a b"}, "fleet name"),
    ({"port": 0}, "--port must be"),
    ({"addresses": []}, "'addresses'"),
])
def test_a_damaged_manifest_is_one_line_naming_the_field(tmp_path, change, words):
    (tmp_path / MANIFEST).write_text(json.dumps({**_manifest(tmp_path), **change}))
    with pytest.raises(UavRobotsError, match="fleet.json") as exc:
        read_fleet_dir(tmp_path)
    assert words in str(exc.value) and "\n" not in str(exc.value)


# ------------------------------------------------------------------ payloads: a byte limit per type (item 13)

WORST_FLOAT = -2.2250738585072014e-308   # the longest a double writes: 24 characters
WORST_CHAR = "\U0001F600"                # escaped as a surrogate pair: 12 bytes


def _longest(tp):
    """The value of type `tp` whose JSON text is longest within its bounds."""
    from typing import Literal, get_args, get_origin

    base, meta = unwrap(tp)
    origin = get_origin(base)
    if base is bool:
        return False
    if base is int:
        r = bound(meta, Range)
        return r.lo if len(str(r.lo)) > len(str(r.hi)) else r.hi
    if base is float:
        r = bound(meta, Range)
        return WORST_FLOAT if r.lo <= WORST_FLOAT <= r.hi and not (r.open_lo and WORST_FLOAT <= r.lo) else float(r.hi)
    if base is str:
        n = bound(meta, MaxLen).n
        return "1" * n if bound(meta, Pattern) else WORST_CHAR * n
    if base is bytes:
        return b""
    if origin is Literal:
        return max(get_args(base), key=lambda a: len(json.dumps(a)))
    if origin is tuple:
        return tuple(_longest(a) for a in get_args(base))
    if origin is list:
        return [_longest(get_args(base)[0])] * bound(meta, MaxLen).n
    raise TypeError(tp)


BOUNDED = [c for c in MESSAGE_TYPES.values() if json_limit(c) < c.json_cap_bytes]


def test_each_type_has_its_own_limit_and_the_small_ones_are_small():
    limits = {n: json_limit(c) for n, c in MESSAGE_TYPES.items()}
    for small in ("Done", "MoveRequest", "CameraRequest", "WorldInfoRequest", "RecordRequest", "VehiclePose"):
        assert limits[small] <= 8 * 1024, (small, limits[small])
    for text_bound in ("RobotState", "PlanAck", "Tick", "MoveResult", "MissionEnd", "MissionStatus"):
        assert limits[text_bound] <= 128 * 1024, (text_bound, limits[text_bound])   # two strings of 4,096 at most
    assert limits["Plan"] < 2 * 2**20 and limits["MoveBatch"] < 3 * 2**20
    assert max(limits[n] for n in limits if n != "Record") == MAX_MESSAGE_BYTES


@pytest.mark.parametrize("cls", BOUNDED, ids=lambda c: c.__name__)
def test_the_longest_message_of_a_type_fits_its_limit_and_the_limit_is_tight(cls):
    """Every field at its longest (the worst escapes a JSON writer may use) decodes; the limit leaves
    only the margin for unknown fields above it; a byte more than the limit is refused unparsed."""
    msg = cls(**{f.name: _longest(f.type) for f in wire_fields(cls)})
    data = encode(msg)
    head = data.partition(b"\0")[0]
    assert decode(data, cls) == msg
    assert json_limit(cls) - MARGIN_BYTES - 1024 - 16 <= len(head) <= json_limit(cls) - MARGIN_BYTES
    over = head[:-1] + b',"x":"' + b"y" * (json_limit(cls) - len(head) - 6) + b'"}' + data[len(head):]
    assert len(over.partition(b"\0")[0]) == json_limit(cls) + 1
    with pytest.raises(ProtocolError, match="over the limit of"):
        decode(over, cls)


def test_the_issues_unknown_field_is_refused_before_it_is_parsed():
    """A RobotState carrying a path of pairs it does not know: accepted under the old 8 MiB limit for
    every type (2.5 s to decode the issue's 8 MB on a loaded machine), refused by its length now."""
    base = encode(RobotState(robot=1, tick=3, cell=(2, 2), status="stepping"))
    pairs = b",".join([b"[1234,5678]"] * 100_000)
    junk = base[:-1] + b',"path":[' + pairs + b"]}"
    assert json_limit(RobotState) < len(junk) < MAX_MESSAGE_BYTES
    with pytest.raises(ProtocolError, match=f"over the limit of {json_limit(RobotState)}"):
        decode(junk, RobotState)
    near = base[:-1] + b',"path":[' + b",".join([b"[1,2]"] * 1000) + b"]}"   # unknown fields within the margin
    assert decode(near, RobotState).cell == (2, 2)


def test_the_documented_limits_are_the_decoders():
    """docs/protocol.md's table of byte limits names each type's limit as json_limit computes it."""
    import re

    text = (REPO / "docs" / "protocol.md").read_text()
    table = text[text.index("| message type | payload limit"):]
    table = table[:table.index("\n\n")]
    rows = dict(re.findall(r"^\| `(\w+)` \| ([\d,]+) bytes", table, re.M))
    assert set(rows) == set(MESSAGE_TYPES)
    for name, cls in MESSAGE_TYPES.items():
        assert int(rows[name].replace(",", "")) == json_limit(cls), name


def test_an_oversize_payload_is_counted_where_rejects_are():
    """The UAV's fleet link counts it as it counts every message that does not decode, and keeps its state."""
    from protocol.keys import Keys
    from protocol.transport import MemoryBus, MemoryTransport
    from uav_agent.fleet import FleetLink

    bus = MemoryBus()
    keys = Keys("t")
    link = FleetLink(MemoryTransport(bus), keys)
    link.clock = 3
    robot = MemoryTransport(bus)
    try:
        robot.put(keys.state(1), encode(RobotState(robot=1, tick=3, cell=(2, 2), status="stepping")))
        big = encode(RobotState(robot=1, tick=3, cell=(5, 5), status="stepping"))
        robot.put(keys.state(1), big[:-1] + b',"x":"' + b"y" * json_limit(RobotState) + b'"}')
        assert link.rejected == 1 and link.cells == {1: (2, 2)}
    finally:
        link.close()
        robot.close()


@pytest.mark.process
def test_a_robot_process_drops_and_reports_an_oversize_plan_and_serves_the_next():
    """A real robot over a real Zenoh router: a plan with a 2 MB unknown field (under the old 8 MiB
    limit, so it was acknowledged) is dropped, said once on stderr, and the next plan is served."""
    from conformance import FakeUav, Hub, stop_process
    from scenes import robot_process

    with Hub() as hub:
        uav = FakeUav(hub.transport, hub.keys)
        proc = robot_process(hub, "0")
        try:
            assert uav.until(lambda: 0 in uav.alive, 10)
            plan = encode(Plan(robot=0, plan_id="big", path=[(1, 1), (1, 2)], goal=(1, 2)))
            hub.transport.put(hub.keys.plan(0), plan[:-1] + b',"x":"' + b"y" * 2_000_000 + b'"}')
            uav.plan(0, "small", [(1, 1), (1, 2)])
            ack = uav.ack_for(0, "small", 10)
            assert ack is not None and ack.ok
            assert uav.ack_for(0, "big", 0.5) is None, "the oversize plan was served"
            uav.end(True)
            proc.wait(15)
            err = proc.stderr.read()
            assert "Plan: payload of 2000" in err and f"over the limit of {json_limit(Plan)}" in err, err[-500:]
        finally:
            stop_process(proc)
            uav.close()


def test_a_batch_is_bounded_by_the_robots_its_receiver_asked_about():
    """The issue's own example: a MoveBatchResult carrying a million-pair unknown field (8 MB) fits the
    type's 8 MiB cap, but the answer to one robot's (or eight robots') query may take only what that
    many entries can: it is refused on its length, before any parsing."""
    from protocol.codec import batch_limit, decode, encode, json_limit
    from protocol.errors import ProtocolError
    from protocol.messages import MoveBatchResult, StateBatch

    junk = encode(MoveBatchResult(tick=1, results=[(7, True, (1, 1), "")]))[:-1] + b',"path":' + \
        b"[" + b",".join(b"[1,2]" for _ in range(1_000_000)) + b"]}"
    assert len(junk) < json_limit(MoveBatchResult)
    for robots in (1, 8):
        with pytest.raises(ProtocolError, match=f"over the limit of {batch_limit(MoveBatchResult, robots)} "
                                                f"for {robots} robot"):
            decode(junk, MoveBatchResult, robots)
    # a full answer for the robots asked about still fits
    full = MoveBatchResult(tick=1, results=[(r, False, (1, 1), "x" * 4096) for r in range(8)])
    assert decode(encode(full), MoveBatchResult, 8) == full
    assert batch_limit(StateBatch, 1) < batch_limit(StateBatch, 8) <= json_limit(StateBatch)
