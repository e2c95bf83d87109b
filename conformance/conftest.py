"""Options and fixtures of the robot and UAV conformance suites.

    python -m pytest conformance/test_robot_*.py \
        --robot-cmd "my-robot --id {id} --fleet {fleet} --router {endpoint}"
    python -m pytest conformance/test_uav_*.py \
        --uav-cmd "my-uav --fleet {fleet} --router {endpoint} --mavlink {mavlink} --robots {robots}"
"""
from __future__ import annotations

import tempfile
from pathlib import Path

import pytest

from conformance import DEFAULT_POOL_CMD, DEFAULT_ROBOT_CMD, FakeUav, FakeWorld, Hub, start_robot, stop_process
from conformance.rules import newer_rules, since_of_test
from conformance.suite_files import side_of
from conformance.uav_harness import DEFAULT_UAV_CMD, PLACEHOLDERS, UavOptions, uav_command
from conformance.uav_missions import SLOW, in_the_background
from protocol.errors import MissionError
from protocol.messages import PROTOCOL_VERSION

# The suites' shared steps assert too: rewritten as the tests are (before a test module imports them),
# their failures show the values compared.
pytest.register_assert_rewrite("conformance.robot_steps", "conformance.uav_steps")
_PROTOCOL = pytest.StashKey[tuple[int, str]]()   # the robot's protocol version, and how the suite knows it


def pytest_addoption(parser: pytest.Parser) -> None:
    group = parser.getgroup("uav-robots conformance")
    group.addoption("--robot-cmd", default=DEFAULT_ROBOT_CMD,
                    help="command line of the robot under test; placeholders {id} {fleet} {endpoint}")
    group.addoption("--robot-pool-cmd", default=None,
                    help="command line of a pool hosting several robots; placeholders {ids} (comma-separated) "
                         "{fleet} {endpoint} (default: our pool when --robot-cmd is ours; else the pool test is skipped)")
    group.addoption("--robot-ahead-cmd", default=None,
                    help="command line of the robot moving ahead (optional, docs/protocol.md 'Moving ahead'); "
                         "placeholders as --robot-cmd (default: ours with --moves ahead when --robot-cmd is ours; "
                         "else the test of that mode is skipped)")
    group.addoption("--robot-pool-ahead-cmd", default=None,
                    help="command line of a pool moving ahead; placeholders as --robot-pool-cmd (default: ours with "
                         "--moves ahead when --robot-cmd is ours; else the test of that mode is skipped)")
    group.addoption("--robot-id", type=int, default=7, help="the robot id to start it with")
    group.addoption("--robot-timeout", type=float, default=10.0,
                    help="seconds a robot gets to come alive (and to answer anything)")
    group.addoption("--robot-protocol", type=int, default=None, metavar="N",
                    help="the protocol version the robot keeps (default: the `protocol` its first PlanAck states; "
                         "none stated: 1); it is held to the rules of that version, and every PlanAck must state it")
    d = UavOptions()
    group.addoption("--uav-cmd", default=DEFAULT_UAV_CMD,
                    help=f"command line of the UAV under test; placeholders {PLACEHOLDERS} "
                         "({mavlink} is udpin://127.0.0.1:{mavlink_port}, where the simulated vehicle sends)")
    group.addoption("--uav-map", default=d.map, help=f"the world's map for UAV missions (default {d.map})")
    group.addoption("--uav-robots", type=int, default=d.robots, help=f"robots in UAV missions (default {d.robots})")
    group.addoption("--uav-seed", type=int, default=d.seed, help="seed of the world's placement")
    group.addoption("--uav-time-scale", type=float, default=d.time_scale,
                    help=f"simulated seconds per second of the MAVLink vehicle (default {d.time_scale:g})")
    group.addoption("--uav-tick-timeout", type=float, default=d.tick_timeout_s,
                    help="the UAV's tick barrier timeout, passed as {tick_timeout}; the UAV must end a mission "
                         "with a silent robot within this plus 10 s (default %(default)s)")
    group.addoption("--uav-timeout", type=float, default=d.mission_timeout_s,
                    help="seconds a whole UAV mission may take before the UAV is killed (default %(default)s)")


@pytest.fixture
def robot_cmd(request: pytest.FixtureRequest) -> str:
    return request.config.getoption("--robot-cmd")


def _optional_cmd(request: pytest.FixtureRequest, option: str, ours: str, skip: str) -> str:
    """The command line given with `option`; ours when the robot under test is ours; else the test is skipped."""
    cmd = request.config.getoption(option)
    if cmd is None and request.config.getoption("--robot-cmd") == DEFAULT_ROBOT_CMD:
        cmd = ours
    if not cmd:
        pytest.skip(skip)
    return cmd


@pytest.fixture
def pool_cmd(request: pytest.FixtureRequest) -> str:
    return _optional_cmd(request, "--robot-pool-cmd", DEFAULT_POOL_CMD,
                         "no --robot-pool-cmd given: the implementation is checked as a single robot only")


@pytest.fixture
def ahead_cmd(request: pytest.FixtureRequest) -> str:
    return _optional_cmd(request, "--robot-ahead-cmd", DEFAULT_ROBOT_CMD + " --moves ahead",
                         "no --robot-ahead-cmd given: moving ahead is optional, and not checked")


@pytest.fixture
def pool_ahead_cmd(request: pytest.FixtureRequest) -> str:
    return _optional_cmd(request, "--robot-pool-ahead-cmd", DEFAULT_POOL_CMD + " --moves ahead",
                         "no --robot-pool-ahead-cmd given: a pool moving ahead is optional, and not checked")


@pytest.fixture(scope="session")
def robot_protocol(request: pytest.FixtureRequest) -> int:
    """The protocol version the robot under test keeps: given, or read from the first PlanAck of a robot
    started for that alone (docs/protocol.md, Versioning)."""
    config = request.config
    given = config.getoption("--robot-protocol")
    if given is not None:
        config.stash[_PROTOCOL] = (given, "given with --robot-protocol")
        return given
    rid, timeout = config.getoption("--robot-id"), config.getoption("--robot-timeout")
    with tempfile.TemporaryDirectory() as tmp, Hub() as hub:
        uav, world = FakeUav(hub.transport, hub.keys), FakeWorld(hub.transport, hub.keys)
        raw: list[bytes] = []
        sub = hub.transport.subscribe(hub.keys.ack(rid), lambda _key, payload: raw.append(payload))
        proc = start_robot(config.getoption("--robot-cmd"), rid, hub.fleet, hub.endpoint, Path(tmp) / "probe.log")
        try:
            ack = None
            if uav.until(lambda: rid in uav.alive or proc.poll() is not None, timeout) and proc.poll() is None:
                uav.plan(rid, "p-protocol", [(2, 2), (3, 2)])
                ack = uav.ack_for(rid, "p-protocol", timeout)
        finally:
            stop_process(proc)
            sub.close()
            uav.close()
            world.close()
    if ack is None:   # the tests say what is wrong; hold it to every rule meanwhile
        config.stash[_PROTOCOL] = (PROTOCOL_VERSION, "no PlanAck to read it from: held to every rule")
        return PROTOCOL_VERSION
    stated = any(b'"protocol"' in payload for payload in raw[:1])
    config.stash[_PROTOCOL] = (ack.protocol, "stated in its first PlanAck" if stated else "its first PlanAck states none")
    return ack.protocol


@pytest.fixture(autouse=True)
def _rules_of_its_version(request: pytest.FixtureRequest) -> None:
    """A robot is held to the rules of the protocol version it keeps: a test of a newer rule is skipped."""
    if side_of(request.module.__name__) != "robot":
        return
    version = request.getfixturevalue("robot_protocol")
    test = request.node.originalname
    if version < since_of_test("robot", test):
        newer = [r.id for r in newer_rules("robot", version) if test in r.tests]
        pytest.skip(f"{', '.join(newer)}: newer than protocol {version}, which the robot keeps")


def pytest_terminal_summary(terminalreporter, exitstatus: int, config: pytest.Config) -> None:
    """One line: which protocol the robot keeps, and what that leaves unchecked."""
    if _PROTOCOL not in config.stash:
        return
    version, how = config.stash[_PROTOCOL]
    terminalreporter.write_line(protocol_line(version, how))


def protocol_line(version: int, how: str) -> str:
    newer = newer_rules("robot", version)
    if not newer:
        extra = f", newer than this suite's {PROTOCOL_VERSION}: held to protocol {PROTOCOL_VERSION}'s rules" \
            if version > PROTOCOL_VERSION else ": held to every robot rule"
        return f"robot protocol: the implementation keeps protocol {version} ({how}){extra}"
    return (f"robot protocol: the implementation keeps protocol {version} ({how}): not held to the rules of "
            f"protocol {version + 1} and later ({', '.join(r.id for r in newer)}, skipped); a protocol "
            f"{PROTOCOL_VERSION} UAV refuses it on a secured fleet (`--secure`: access control leaves the plain "
            f"`P/world/move` it asks on unreachable) and serves it otherwise (docs/protocol.md, Versioning)")


@pytest.fixture
def rid(request: pytest.FixtureRequest) -> int:
    return request.config.getoption("--robot-id")


@pytest.fixture
def timeout(request: pytest.FixtureRequest) -> float:
    return request.config.getoption("--robot-timeout")


@pytest.fixture
def hub():
    with Hub() as h:
        yield h


@pytest.fixture
def uav(hub):
    u = FakeUav(hub.transport, hub.keys)
    yield u
    u.close()


@pytest.fixture
def world(hub):
    w = FakeWorld(hub.transport, hub.keys)
    yield w
    w.close()


@pytest.fixture
def spawn(hub, robot_cmd, rid, tmp_path):
    """Start the robot under test; always stopped (and killed if need be) afterwards."""
    procs = []

    def start(template: str | None = None, ids: list[int] | None = None):
        proc = start_robot(template or robot_cmd, ids or rid, hub.fleet, hub.endpoint,
                           tmp_path / f"robot-{len(procs)}.log")
        procs.append(proc)
        return proc

    yield start
    for p in procs:
        stop_process(p)


@pytest.fixture
def robot(spawn, uav, world, rid, timeout, tmp_path):
    """A running robot whose liveliness token has been seen."""
    proc = spawn()
    if not uav.until(lambda: rid in uav.alive or proc.poll() is not None, timeout):
        pytest.fail(f"robot {rid} declared no liveliness token within {timeout:g} s; log:\n{_log(tmp_path)}")
    if proc.poll() is not None:
        pytest.fail(f"robot {rid} exited with code {proc.returncode} at startup; log:\n{_log(tmp_path)}")
    return proc


def _log(tmp_path) -> str:
    return "\n".join(p.read_text(errors="replace")[-2000:] for p in sorted(tmp_path.glob("robot-*.log")))


@pytest.fixture(scope="session")
def uav_options(request: pytest.FixtureRequest) -> UavOptions:
    o = request.config.getoption
    try:  # a bad placeholder is a usage error: one line, and nothing is started
        uav_command(o("--uav-cmd"), fleet="f", endpoint="tcp/127.0.0.1:1", mavlink_port=1, robots=1, tick_timeout=1)
    except MissionError as exc:
        pytest.exit(f"error: {exc}", returncode=4)
    return UavOptions(cmd=o("--uav-cmd"), map=o("--uav-map"), robots=o("--uav-robots"), seed=o("--uav-seed"),
                      time_scale=o("--uav-time-scale"), tick_timeout_s=o("--uav-tick-timeout"),
                      mission_timeout_s=o("--uav-timeout"))


@pytest.fixture(scope="session", autouse=True)
def _slow_missions_in_the_background(request: pytest.FixtureRequest):
    """The UAV suite's slow missions whose tests are selected start with the session, in whichever file of the
    suite it begins, and run beside the other missions (conformance/uav_missions.py)."""
    wanted = sorted({name for item in request.session.items for name in getattr(item, "fixturenames", ())
                     if name in SLOW})
    if not wanted:   # the robot suite, or no test of a slow mission selected
        yield
        return
    with in_the_background(wanted, request.getfixturevalue("uav_options"),
                           request.getfixturevalue("tmp_path_factory")):
        yield
