import socket

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
