"""`uav-robots bench mission`: whole missions run as a user runs them, each row from its own report."""
from __future__ import annotations

import json
import subprocess
import sys

import pytest

pytestmark = pytest.mark.process   # every test here starts a process

BENCH_TIMEOUT_S = 300


def bench(tmp_path, *args: str) -> tuple[subprocess.CompletedProcess, str, dict]:
    out = tmp_path / "results"
    done = subprocess.run([sys.executable, "-m", "uav_robots", "bench", "mission", "--out", str(out), *args],
                          capture_output=True, text=True, timeout=BENCH_TIMEOUT_S)
    table = (out / "mission.md").read_text() if (out / "mission.md").exists() else ""
    data = json.loads((out / "mission.json").read_text()) if (out / "mission.json").exists() else {}
    return done, table, data


@pytest.mark.slow
def test_the_default_mission_twice_gives_two_rows_from_their_reports(tmp_path):
    done, table, data = bench(tmp_path, "--runs", "2", "--map", "default", "--robots", "0", "--target-s", "10")
    assert done.returncode == 0, done.stdout + done.stderr
    runs = data["runs"]
    assert [r["run"] for r in runs] == [1, 2]
    for r in runs:
        assert (r["exit"], r["outcome"], r["verified"], r["collisions"]) == (0, "completed", "8/8", 0)
        # the phases come from the run's own report; the summary line comes before the exit
        report = json.loads((tmp_path / "results" / r["out"] / "report.json").read_text())
        timings = report["timings"]
        assert r["survey_perceive_s"] == round(timings["survey"] + timings["perceive"], 2)
        assert 0 < r["survey_perceive_s"] < r["summary_s"] <= r["wall_s"]
    assert "completed (exit 0): 2 of 2" in table and "within 10 s: " in table
    assert not any(r["out"].startswith("/") for r in runs), "no absolute path in what may be committed"


def test_a_run_that_fails_is_a_row_with_its_error_and_the_bench_exits_non_zero(tmp_path):
    done, table, data = bench(tmp_path, "--runs", "1", "--run-args", "--map nosuchmap")
    assert done.returncode == 1
    (r,) = data["runs"]
    assert r["exit"] != 0 and r["outcome"] == "no report" and "unknown map 'nosuchmap'" in r["error"]
    assert "completed (exit 0): 0 of 1" in table and "unknown map 'nosuchmap'" in table
    assert "Traceback" not in done.stdout + done.stderr


def test_bad_bench_arguments_are_one_line_errors(tmp_path):
    for args, why in ((["--runs", "0"], "--runs must be at least 1"), (["--run-args", "'unclosed"], "--run-args")):
        done, _, _ = bench(tmp_path, *args)
        assert done.returncode != 0 and why in done.stderr + done.stdout
        assert "Traceback" not in done.stderr
