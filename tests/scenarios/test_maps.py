"""MovingAI files, generators, placement, the shipped benchmark data."""
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from protocol.errors import MapError
from protocol.mapfile import ScenAgent, read_map, read_scen, write_map, write_scen
from scenarios.benchmarks import DATA, grid_hash, movingai_map, movingai_scen, paper_scen, paper_warehouse
from scenarios.maps import largest_component, place, random_map, resolve_map, warehouse


def test_map_round_trip(tmp_path):
    free = random_map(13, 7, 0.3, seed=1)
    write_map(tmp_path / "m.map", free)
    assert (read_map(tmp_path / "m.map") == free).all()
    agents = [ScenAgent((0, 0), (1, 1), 1.5)]
    free[0, 0] = free[1, 1] = True
    write_scen(tmp_path / "m.scen", "m.map", free, agents)
    assert read_scen(tmp_path / "m.scen", free) == agents


def test_warehouse_450_is_the_papers_benchmark_map():
    free = paper_warehouse()   # regenerated and checked against the published map's hash
    assert (warehouse(33, 112) == free).all()
    assert free.sum() == 126_784
    agents = read_scen(paper_scen(1), free, agents=50)
    assert len(agents) == 50
    changed = free.copy()
    changed[1, 1] = not changed[1, 1]
    assert grid_hash(changed) != grid_hash(free)


def test_every_shipped_benchmark_loads():
    for m in sorted(p.name for p in (DATA / "movingai").iterdir() if p.is_dir()):
        free = read_map(movingai_map(m))
        for s in ("random-1", "even-5"):
            assert len(read_scen(movingai_scen(m, s), free, 10)) == 10


def test_a_missing_benchmark_file_is_one_line_naming_it():
    with pytest.raises(MapError, match=r"benchmark file not found: .*10000agents-1.scen \(it is not shipped"):
        movingai_scen("warehouse-20-40-10-2-2", "10000agents-1")


@pytest.mark.parametrize("text, needle", [
    ("", "no 'map' line"),
    ("type octile\nheight 2\nwidth 2\nmap\n..\n", "2 rows, file has 1"),
    ("type octile\nheight x\nwidth 2\nmap\n..\n..\n", "not integers"),
    ("type octile\nwidth 2\nmap\n..\n", "lacks 'height'"),
    ("type octile\nheight 2\nwidth 3\nmap\n..\n..\n", "width 3"),
    ("type octile\nheight 2\nwidth 2\nmap\n..\n...\n", "row 1 has 3"),
])
def test_malformed_maps(tmp_path, text, needle):
    (tmp_path / "bad.map").write_text(text)
    with pytest.raises(MapError) as exc:
        read_map(tmp_path / "bad.map")
    assert needle in str(exc.value)


def test_missing_files():
    with pytest.raises(MapError, match="not found"):
        read_map("/nonexistent/x.map")
    with pytest.raises(MapError, match="unknown map"):
        resolve_map("nonsense")
    with pytest.raises(MapError, match="unknown map"):
        resolve_map("..")


def test_a_shipped_movingai_map_is_named_as_bench_movingai_names_it():
    from scenarios.benchmarks import movingai_map

    name, free = resolve_map("room-64-64-8")
    assert name == "room-64-64-8"
    assert (free == read_map(movingai_map("room-64-64-8"))).all()


def test_scen_checks_cells(tmp_path):
    free = np.ones((3, 3), bool)
    free[1, 1] = False
    (tmp_path / "s.scen").write_text("version 1\n0\tm\t3\t3\t1\t1\t0\t0\t2\n")
    with pytest.raises(MapError, match=r"start \(1, 1\) is not a free cell"):
        read_scen(tmp_path / "s.scen", free)
    with pytest.raises(MapError, match="asked for 5 agents"):
        read_scen(tmp_path / "s.scen", agents=5)
    assert read_scen(tmp_path / "s.scen", agents=0) == []
    (tmp_path / "neg.scen").write_text("version 1\n0\tm\t3\t3\t-1\t0\t0\t0\t2\n")
    with pytest.raises(MapError, match="line 2 has a negative coordinate"):
        read_scen(tmp_path / "neg.scen")  # numpy would wrap -1 round to the last column
    with pytest.raises(MapError, match="cannot read scenario file"):
        read_scen(tmp_path)


def test_too_many_robots():
    _, free = resolve_map("warehouse-small")
    with pytest.raises(MapError, match="need 1000 free connected cells"):
        place(free, 500, 0)


@settings(max_examples=30, deadline=None)
@given(w=st.integers(4, 30), h=st.integers(4, 30), d=st.floats(0, 0.4), seed=st.integers(0, 100),
       n=st.integers(1, 6))
def test_placement_distinct_free_connected(w, h, d, seed, n):
    free = random_map(w, h, d, seed)
    region = largest_component(free)
    if 2 * n > region.sum():
        with pytest.raises(MapError):
            place(free, n, seed)
        return
    p = place(free, n, seed)
    cells = p.starts + p.goals
    assert len(set(cells)) == 2 * n
    assert all(region[y, x] for x, y in cells)
    assert place(free, n, seed) == p  # seeded


def test_named_and_parametric_specs():
    assert resolve_map("warehouse-small")[1].shape == (18, 24)
    assert resolve_map("warehouse:blocks_x=2,blocks_y=2,dock=2")[1].shape[0] > 0
    _, f = resolve_map("random:width=20,height=10,density=0.1")
    assert f.shape == (10, 20)
    with pytest.raises(MapError, match="not name=number"):
        resolve_map("random:width")
