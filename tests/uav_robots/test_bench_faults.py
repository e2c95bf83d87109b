"""`uav-robots bench faults` judges each scenario from its own report and the world's record."""
from uav_robots.bench.faults import judge, scenarios, table


def _report(outcome="completed", collisions=0, verified=None):
    return {"outcome": outcome, "collisions": collisions, "safety_stops": 0, "replans": 1,
            "verified": verified if verified is not None else {"0": True, "1": True},
            "truth": {"goals": [[1, 1], [2, 2]]}, "out_of_plan": {}}


DETAILS = {"executed": {"0": [[0, 0], [1, 1]], "1": [[3, 3], [2, 2]]}}


def test_completed_or_degraded_with_a_true_report_passes():
    assert judge("a", [], 0, _report(), DETAILS, 1.0).passed
    degraded = _report("degraded", verified={"0": True, "1": False})
    assert judge("a", [], 3, degraded, DETAILS, 1.0).passed


def test_what_fails_a_scenario():
    assert judge("a", [], 1, _report("aborted"), DETAILS, 1.0).why == "exit 1; exit 1 with outcome aborted"
    assert "2 collisions" in judge("a", [], 0, _report(collisions=2), DETAILS, 1.0).why
    off = {"executed": {"0": [[0, 0], [1, 1]], "1": [[3, 3], [3, 4]]}}
    assert "robots ['1'] called verified off every goal" in judge("a", [], 0, _report(), off, 1.0).why
    assert judge("a", [], 0, _report("degraded"), DETAILS, 1.0).why == "exit 0 with outcome degraded"
    assert not judge("a", [], -1, None, None, 1.0).passed


def test_the_catalogue_and_its_table():
    names = [n for n, _ in scenarios()]
    assert len(names) == len(set(names)) == 36 and len(scenarios(quick=True)) == 14
    rows = [judge("a", ["--robots", "4"], 0, _report(), DETAILS, 1.0)]
    assert table(rows).startswith("1 of 1 fault scenarios ended as they should")
