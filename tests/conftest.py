import os
import socket
import subprocess

import pytest


def _free_port(kind=socket.SOCK_STREAM) -> int:
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture
def zenoh_endpoint() -> str:
    return f"tcp/127.0.0.1:{_free_port()}"


@pytest.fixture
def udp_port() -> int:
    return _free_port(socket.SOCK_DGRAM)


@pytest.fixture
def vehicle():
    """The simulated autopilot listening on a free loopback UDP port, 20x faster than real time."""
    from sim_world.vehicle import Vehicle, VehicleConfig

    v = Vehicle(VehicleConfig(url="udpin:127.0.0.1:0", time_scale=20.0)).start()
    yield v
    v.stop()


@pytest.fixture
def mem_world(tmp_path):
    """A world on an in-memory bus (three robots on a small map, no vehicle) and a client of that bus."""
    from protocol.transport import MemoryBus, MemoryTransport
    from scenes import open_map
    from sim_world.config import WorldConfig
    from sim_world.service import World

    m, s = open_map(tmp_path, [(0, 0), (1, 0), (5, 5)], [(7, 0), (7, 1), (5, 4)])
    bus = MemoryBus()
    world = World(WorldConfig(fleet="t", map=m, scen=s, robots=3, mavlink=None, move_batch_timeout_s=0.4),
                  MemoryTransport(bus))
    world.start()
    client = MemoryTransport(bus)
    yield world, client
    client.close()
    world.close()


# A test that starts a process (a command, a world, a UAV, robots, a vehicle) is marked `process`, so
# that `-m "not process"` is a lane of tests that run in this process alone. An unmarked test that starts
# one fails; UAV_ROBOTS_LIST_PROCESSES=FILE lists such tests in FILE instead (to mark a new suite).
@pytest.fixture(autouse=True)
def _processes_are_marked(request, monkeypatch):
    started: list = []
    real = subprocess.Popen.__init__

    def spy(self, *args, **kwargs):
        started.append(args[0] if args else kwargs.get("args"))
        real(self, *args, **kwargs)

    monkeypatch.setattr(subprocess.Popen, "__init__", spy)
    yield
    if not started or request.node.get_closest_marker("process") is not None:
        return
    listing = os.environ.get("UAV_ROBOTS_LIST_PROCESSES")
    if listing:
        with open(listing, "a") as f:
            f.write(request.node.nodeid + "\n")
        return
    pytest.fail(f"starts a process ({str(started[0])[:80]}) but is not marked `process`", pytrace=False)
