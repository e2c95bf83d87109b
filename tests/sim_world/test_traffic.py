"""The world's movers in its tick: placed from the scene, scripted routes read from a file, stepped
with the robots' moves, every robot-mover contact counted as a collision, and published for observers."""
from __future__ import annotations

import json
import threading

import numpy as np
import pytest

from conformance import Hub
from protocol.codec import decode, encode
from protocol.config import client_config
from protocol.errors import MapError, UavRobotsError
from protocol.messages import FloorMovers, MoveRequest, MoveResult, Record, RecordRequest
from protocol.run_spec import SceneSpec
from protocol.transport import ZenohTransport
from scenarios.floor import setup_floor
from scenarios.scene import scene_options
from sim_world.config import WorldConfig
from sim_world.movers import FORKLIFT, PALLET, PERSON, Mover, read_routes
from sim_world.moves import MoveJudge
from sim_world.service import World
from sim_world.traffic import Traffic, build_traffic
from scenes import open_map

OPEN = np.ones((5, 7), bool)


def routes(tmp_path, movers) -> str:
    path = tmp_path / "routes.json"
    path.write_text(json.dumps({"movers": movers}))
    return str(path)


def test_the_scene_places_its_movers_off_the_robots_and_goals():
    floor = setup_floor("warehouse-small", 3, 8)
    traffic = build_traffic(scene_options("ideal,people=4,forklifts=2,pallets=3"), floor.free, floor.starts,
                            floor.goals, 3)
    kinds = [m.kind for m in traffic.movers]
    assert kinds.count(PERSON) == 4 and kinds.count(FORKLIFT) == 2 and kinds.count(PALLET) == 3
    cells = {m.cell for m in traffic.movers}
    assert len(cells) == 9 and not cells & (set(floor.starts) | set(floor.goals))
    assert all(floor.free[y, x] for x, y in cells)
    assert build_traffic(scene_options("ideal"), floor.free, floor.starts, floor.goals, 3) is None


def test_the_mover_flags_add_people_or_forklifts_and_survive_the_specs_text():
    scene = scene_options("ideal,pallets=1", "ideal", movers=5, mover_speed=2)
    assert (scene.people, scene.forklifts, scene.pallets) == (0, 5, 1)
    assert scene_options(scene.text()) == scene
    for bad, needle in (("people=-1", "people -1"), ("people=x", "not name=whole number"),
                        ("routes=nowhere.json", "no such file")):
        with pytest.raises(UavRobotsError, match=needle):
            scene_options(bad)
    with pytest.raises(UavRobotsError, match="--mover-speed 3"):
        scene_options("", movers=1, mover_speed=3)


def test_a_scripted_person_walks_its_waypoints_in_turn_and_a_dropped_pallet_waits_for_robots_to_leave(tmp_path):
    path = routes(tmp_path, [{"kind": "person", "route": [[0, 0], [6, 0], [6, 4]], "loop": False},
                             {"kind": "pallet", "at": [3, 3], "tick": 2}])
    movers = read_routes(path, OPEN)
    traffic = Traffic(OPEN, movers)
    judge = MoveJudge(OPEN.copy(), {0: (3, 4)}, 4, traffic=traffic)
    for t in range(1, 4):   # the robot next to the pallet's cell keeps it from falling
        judge.resolve(t, {})
    assert [m.appears for m in traffic.movers][1] == 4
    judge.resolve(4, {0: ((3, 4), (2, 4))})
    judge.resolve(5, {0: ((2, 4), (1, 4))})
    assert all(m.cell != (3, 3) for m in traffic.on_floor(5)) and traffic.movers[1].appears == 6
    for t in range(6, 16):
        judge.resolve(t, {})
    person = traffic.trace[0]
    assert person[:7] == [(x, 0) for x in range(7)] and person[-1] == (6, 4)
    assert all(abs(a[0] - b[0]) + abs(a[1] - b[1]) <= 1 for a, b in zip(person, person[1:]))
    assert (3, 3) in {m.cell for m in traffic.on_floor()} and judge.collisions == 0


@pytest.mark.parametrize("entry, needle", [
    ({"kind": "person", "route": [[9, 0]]}, "off the 7x5 floor"),
    ({"kind": "person", "route": [[1, 1]]}, "is a shelf"),
    ({"kind": "person", "route": [[0, 0], [6, 4]]}, "cannot be reached"),
    ({"kind": "robot", "route": [[0, 0]]}, "needs a kind"),
    ({"kind": "forklift", "route": []}, "needs a route"),
    ({"kind": "pallet", "at": [0, 0], "tick": -1}, "tick is not a whole number"),
    ({"kind": "person", "route": [[0, "a"]]}, r"is not \[x, y\]"),
])
def test_a_routes_file_the_floor_cannot_take_is_one_line(tmp_path, entry, needle):
    free = OPEN.copy()
    free[1, 1] = False
    free[:, 5] = False                       # a wall: the right side cannot be reached
    with pytest.raises(MapError, match=needle):
        read_routes(routes(tmp_path, [entry]), free)


def test_a_routes_file_that_is_not_json_or_starts_on_a_robot_is_one_line(tmp_path):
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    with pytest.raises(MapError, match="routes bad.json: not a JSON file"):
        read_routes(bad, OPEN)
    scene = SceneSpec(routes=routes(tmp_path, [{"kind": "person", "route": [[2, 2]]}]))
    with pytest.raises(MapError, match=r"starts on \[2, 2\], where robot 1 starts"):
        build_traffic(scene, OPEN, [(0, 0), (2, 2)], [(6, 4), (5, 4)], 0)


def test_a_robot_stepping_where_a_mover_stands_or_trading_cells_with_one_is_a_collision():
    pallet = Traffic(OPEN, [Mover(0, PALLET, (2, 0))])
    judge = MoveJudge(OPEN.copy(), {0: (1, 0)}, 4, traffic=pallet)
    judge.resolve(1, {0: ((1, 0), (2, 0))})
    assert judge.mover_collisions == 1 and judge.collisions == 1
    assert pallet.touched[0].how == "same cell" and pallet.touched[0].cell == (2, 0)

    free = np.zeros((1, 3), bool)
    free[0, :] = True                         # a corridor: the person can only walk left, into the robot's cell
    person = Traffic(free, [Mover(0, PERSON, (2, 0), heading=(-1, 0))])
    judge = MoveJudge(free.copy(), {0: (1, 0)}, 4, traffic=person)
    judge.resolve(1, {0: ((1, 0), (2, 0))})  # the person saw the robot's cell taken: it stays, the robot runs into it
    assert judge.mover_collisions == 1 and person.touched[0].how == "same cell"


def test_a_robot_that_stays_is_never_touched_and_near_misses_count_each_approach():
    floor = setup_floor("warehouse-small", 0, 8)
    traffic = build_traffic(SceneSpec(landmark_spacing=0, goal_pads=False, people=6, forklifts=4),
                            floor.free, floor.starts, floor.goals, 0)
    judge = MoveJudge(floor.free, dict(enumerate(floor.starts)), 4, traffic=traffic)
    for t in range(1, 400):
        judge.resolve(t, {})
    assert judge.collisions == 0 and traffic.touched == []
    assert 0 < traffic.near_misses <= traffic.near_miss_ticks
    assert all(len(cells) == 400 for cells in traffic.trace.values())


def test_the_world_publishes_its_movers_and_records_them(tmp_path):
    m, s = open_map(tmp_path, [(0, 0), (2, 0)], [(0, 5), (2, 5)])
    scene = SceneSpec(landmark_spacing=0, goal_pads=False, people=2, pallets=1)
    with Hub() as hub:
        world = World(WorldConfig(fleet=hub.fleet, map=m, scen=s, robots=2, mavlink=None, connect=[hub.endpoint],
                                  scene=scene))
        world.start()
        seen: list[FloorMovers] = []
        got = threading.Event()
        client = ZenohTransport(client_config([hub.endpoint]), "observer")
        try:
            def on(_key, payload):
                seen.append(decode(payload, FloorMovers))
                if seen[-1].tick >= 1:
                    got.set()
            client.subscribe(world.keys.world_movers, on)
            for r, (frm, to) in enumerate((((0, 0), (0, 1)), ((2, 0), (2, 1)))):
                pending = client.request_start(world.keys.move, encode(MoveRequest(robot=r, tick=1, frm=frm, to=to)), 5)
            decode(pending.wait()[0], MoveResult)
            assert got.wait(5), "no FloorMovers after tick 1"
            assert sorted(k for _, k, _ in seen[-1].movers) == [PALLET, PERSON, PERSON]
            rec = decode(client.request(world.keys.record, encode(RecordRequest()), 5)[0], Record)
            movers = rec.truth["movers"]
            assert len(movers["movers"]) == 3 and all(len(t) == 2 for t in movers["trace"].values())
            assert movers["collisions"] == rec.collisions == 0 and movers["contacts"] == []
        finally:
            client.close()
            world.close()
