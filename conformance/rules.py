"""The rules of docs/protocol.md that a robot or a UAV must keep, with the tests that check each.

One table, three readers: docs/conformance-rules.md is written from it
(`python -m conformance.rules --write`; a test fails while the file differs),
`uav-robots conformance --list-rules` prints it, and the mutation test
(tests/test_conformance_mutants.py) breaks each rule in a copy of our own robot
or UAV (`conformance.mutants`) and runs exactly the tests listed here, which
must then fail.
"""
from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass
from pathlib import Path

SUITES = {"robot": "test_robot_conformance.py", "uav": "test_uav_conformance.py"}
DOC = Path(__file__).resolve().parents[1] / "docs" / "conformance-rules.md"


@dataclass(frozen=True)
class Rule:
    id: str                 # R<n> (robots) or U<n> (UAVs)
    section: str            # the docs/protocol.md section it comes from
    text: str               # the rule, as an implementer reads it
    tests: tuple[str, ...]  # test functions (pytest -k names) of the side's suite that check it
    mutant: str             # how the rule's mutant (conformance.mutants) breaks it

    @property
    def side(self) -> str:
        return "robot" if self.id.startswith("R") else "uav"


def _r(n: int, section: str, text: str, tests: tuple[str, ...], mutant: str) -> Rule:
    return Rule(f"R{n}", section, text, tests, mutant)


def _u(n: int, section: str, text: str, tests: tuple[str, ...], mutant: str) -> Rule:
    return Rule(f"U{n}", section, text, tests, mutant)


S, K, M, P, F, E = ("Startup order", "Keys", "Messages", "Plans and ticks", "Faults and recovery", "End of mission")
MALFORMED = "test_a_malformed_plan_is_refused"
FOLLOW = "test_ticks_follow_the_plan_and_done_is_raised_once"
REFUSED = "test_refused_move_leaves_the_robot_in_place"

RULES: tuple[Rule, ...] = (
    # ------------------------------------------------------------ robots
    _r(1, S, "declares its token `alive/robot/<id>` while it runs, and again when restarted on the same id",
       ("test_liveliness_token_appears", "test_restart_gets_a_fresh_token"), "never declares its token"),
    _r(2, S, "subscribes to its plan key, `tick` (moving ahead: `world/judged/<ids>`) and `mission/end` before it "
             "declares its token: a plan put the "
             "moment the token is seen is received", ("test_valid_plan_is_acknowledged",),
       "declares its token 2 s before it subscribes"),
    _r(3, K, "every `PlanAck`, `RobotState` and `Done` names the robot of the key it is put on",
       ("test_messages_name_the_robot_of_their_key",), "its states name robot id + 1"),
    _r(4, P, "acknowledges a valid plan once per `Plan` received: `ok: true`, `error: \"\"`, the plan's `plan_id`",
       ("test_valid_plan_is_acknowledged",), "takes a valid plan without acknowledging it"),
    _r(5, P, "refuses a plan for another robot (`Plan.robot` other than its id)", (MALFORMED,),
       "does not check `Plan.robot`"),
    _r(6, P, "refuses a plan with an empty path", (MALFORMED,), "accepts an empty path"),
    _r(7, P, "refuses a plan with a step that is not a move under the connectivity (a jump; a diagonal when the "
             "plan states 4 or states nothing)", (MALFORMED,), "does not check the steps"),
    _r(8, P, "refuses a plan whose last cell is not `goal`", (MALFORMED,), "does not check the goal"),
    _r(9, P, "refuses a plan (`start_tick` 0 or none) that does not start where the robot stands: a stepping robot "
             "takes a new plan only as a replan from here", ("test_a_plan_not_starting_where_the_robot_stands_is_refused",),
       "does not check the first cell"),
    _r(10, P, "follows the plan's `connectivity` when stated: under 8 a diagonal step is a move, acknowledged and "
              "asked of the world", ("test_diagonal_steps_are_moves_when_the_plan_says_8",),
       "ignores `Plan.connectivity` (uses its own 4)"),
    _r(11, P, "acknowledges a plan resent with the same `plan_id` (and path) again", ("test_a_resent_plan_is_acknowledged_again",),
       "answers a plan id only once"),
    _r(12, P, "refuses a different path under a `plan_id` it already holds",
       ("test_another_path_under_the_same_plan_id_is_refused",), "takes the new path"),
    _r(13, P, "a refusal is `ok: false` with a one-line, non-empty `error`", (MALFORMED,),
       "refuses with an empty `error`"),
    _r(14, M, "drops a message that does not decode, has another `type` or a wrong `v`: no ack for such a plan (not "
              "even `ok: false`), no move on such a tick, no crash, its state kept",
       ("test_garbage_and_wrong_versions_do_not_crash_it",), "answers an undecodable plan with `ok: false`"),
    _r(15, P, "refuses a plan whose `start_tick` is below the last tick it executed",
       ("test_a_repair_plan_for_a_past_tick_is_refused",), "takes a plan for a past tick"),
    _r(16, P, "a repair plan (`start_tick > 0`): `path[0]` is its cell whatever it believed, `path[i]` is its cell at "
              "tick `start_tick + i`", ("test_a_repair_plan_starts_at_its_tick_and_is_switched_to_at_once",),
       "checks a repair plan against its own belief"),
    _r(17, P, "on `Tick(k)` asks the world exactly once (a `MoveRequest` or its entry in a `MoveBatch`) to move to "
              "its plan's cell for `k`; once the plan is over, to stay on its last cell", (FOLLOW,),
       "asks for the cell one tick ahead"),
    _r(18, P, "asks each move from the cell the world last reported (after a refused move: from where it stayed)",
       (REFUSED,), "asks from its plan's cell"),
    _r(19, P, "publishes `RobotState(k, cell)` with the world's cell, accepted or not", (REFUSED,),
       "reports its plan's cell"),
    _r(20, M, "publishes a `RobotState` only for a tick it executes: none for tick 0 (not after the ack), one per "
              "executed tick", ("test_states_only_for_executed_ticks",), "publishes a tick-0 state after its ack"),
    _r(21, M, "a `RobotState` names the plan the robot holds in `plan_id` (never empty once it holds one)",
       ("test_states_name_the_plan_held",), "leaves `plan_id` empty"),
    _r(22, M, "`status` is `stepping` while it executes its plan and `done` once the plan is over and it stands on "
              "its goal", (FOLLOW, "test_states_only_for_executed_ticks"), "never reports `done`"),
    _r(23, M, "when the world does not answer a move, publishes `status: \"error\"` at its last known cell",
       ("test_no_answer_from_the_world_is_an_error_state",), "publishes nothing when the world is silent"),
    _r(24, P, "publishes `Done` once per plan, when the plan is over and it stands on its goal, with that tick and "
              "cell; never while off its goal", (FOLLOW, REFUSED), "raises `Done` on every tick at its goal"),
    _r(25, P, "a robot that has arrived stays on its goal and keeps answering ticks", (FOLLOW,),
       "stops answering ticks once done"),
    _r(26, P, "a tick naming another `plan_id` than the one it holds makes it stay (it asks to stay and reports)",
       ("test_a_tick_for_another_plan_makes_the_robot_stay",), "ignores the tick's `plan_id`"),
    _r(27, M, "ignores a resent or late tick (`k` at or below the last it executed): no move, no state",
       ("test_duplicate_and_late_ticks_are_ignored",), "executes every tick it hears"),
    _r(28, M, "after a gap (`k` more than one above its last tick) executes `k` from where it stands",
       ("test_a_tick_gap_is_executed_from_where_the_robot_stands",), "drops a tick that follows a gap"),
    _r(29, M, "numbers its messages (acks, states, `Done`, move requests) with one counter from 1, one more per "
              "message; `MoveBatch` queries with a counter of their own", ("test_sequence_numbers_count_by_one_from_1",),
       "never increments `seq`"),
    _r(30, P, "a pool (one process hosting several robots) keeps each robot's rules: one move a tick per robot "
              "(in one `MoveBatch` or a `MoveRequest` each), states on each robot's key, each robot's own `seq` "
              "counter", ("test_a_pool_keeps_each_robots_contract",), "a pool asks only its first robot's move"),
    _r(31, E, "exits (code 0) within 5 s of `MissionEnd`, withdrawing its token", ("test_exits_on_mission_end",),
       "ignores `MissionEnd`"),
    _r(32, E, "exits within 5 s of SIGTERM", ("test_exits_on_sigterm",), "ignores SIGTERM"),
    _r(33, E, "exits within 5 s when `alive/uav` disappears after having been seen",
       ("test_exits_when_the_uav_goes_away",), "ignores the UAV's token"),
    _r(34, P, "moving ahead (optional): puts the move of a plan's first tick before its `PlanAck` and the move of "
              "tick k+1 before its state of k, as `MoveAhead` on `P/world/ahead/<ids>` naming its plan; takes its "
              "cell from the world's `MovesJudged`, asks no query; a replan puts a new move for the next tick",
       ("test_a_robot_moving_ahead_puts_each_move_before_what_the_uav_waits_for",),
       "puts its state of tick k before its move of k+1"),
    _r(35, K, "asks its moves on `P/world/move/<ids>`, `<ids>` its own ids, not on the plain `P/world/move` that "
              "access control leaves unreachable", ("test_moves_are_asked_on_the_key_naming_the_robot",),
       "asks on the plain `P/world/move`"),
    _r(36, M, "a pool told `batch_states` may put one `StateBatch` a tick on `P/robots/<ids>/states` (its own ids, "
              "canonical) instead of its robots' `RobotState`s; either way each robot's state of the tick, once",
       ("test_a_pool_told_to_batch_reports_each_robots_state_of_the_tick",),
       "puts its batches on a key naming its first robot only"),
    _r(37, P, "a pool moving ahead (optional) puts one `MoveAhead` per `plan_id` its robots hold, on "
              "`P/world/ahead/<ids>` (its own ids, canonical): a robot holding another plan than the tick's stays",
       ("test_a_pool_moving_ahead_puts_one_move_per_plan_it_holds",),
       "puts every robot's move under the first robot's plan"),
    # ------------------------------------------------------------ UAVs
    _u(1, S, "declares `alive/uav` before it sends any plan and withdraws it when it exits",
       ("test_uav_token_is_up_before_any_plan_and_gone_after_exit",), "never declares `alive/uav`"),
    _u(2, S, "puts plans only to robots whose token is up, and one to every robot",
       ("test_plans_go_only_to_robots_whose_token_is_up",), "also puts a plan to a robot that does not exist"),
    _u(3, P, "every plan starts on the robot's true cell, moves between adjacent free cells and ends on its `goal`; "
             "the goals cover each goal marker once", ("test_every_plan_starts_on_the_robots_true_cell_and_ends_on_a_goal",),
       "names the start as the goal"),
    _u(4, P, "the plans together have no vertex, swap or goal conflict, and the world sees no collision",
       ("test_the_plans_are_conflict_free", "test_the_world_saw_every_robot_reach_its_goal_without_collision"),
       "drives one robot across another's goal after it arrived (its own check off)"),
    _u(5, S, "puts `Tick`s only after every robot acknowledged the plan they name",
       ("test_ticks_start_after_every_ack_and_count_up_by_one",), "does not wait for the acks"),
    _u(6, P, "ticks count 1, 2, ... by one, up to at least the makespan, one `plan_id` per plan",
       ("test_ticks_start_after_every_ack_and_count_up_by_one",), "skips tick 1"),
    _u(7, M, "`Tick.ticks` is the plan's last tick (for a first plan its makespan)", ("test_ticks_start_after_every_ack_and_count_up_by_one",),
       "announces one tick more"),
    _u(8, P, "the tick barrier: `Tick(k+1)` only after every robot in the plan reported tick `k`",
       ("test_the_lockstep_barrier_holds",), "does not wait for the states"),
    _u(9, M, "numbers everything it sends with one counter: `Tick` numbers increase, no two messages share one",
       ("test_uav_sequence_numbers_increase",), "never increments `seq`"),
    _u(10, E, "exactly one `MissionEnd(completed=true)`, after every `Done` and the last tick; exit 0, no traceback",
       ("test_mission_ends_completed_and_the_uav_exits_0",), "puts `MissionEnd` twice"),
    _u(11, E, "lands its vehicle (disarmed, on the ground) after the mission", ("test_the_vehicle_took_off_and_landed",),
       "never lands"),
    _u(12, F, "a refused plan (`ok: false`): no tick, `MissionEnd(completed=false)`, its token withdrawn, exit "
              "non-zero with a last stderr line naming the robot, within the tick timeout + 10 s",
       ("test_a_refused_plan_ends_the_mission_with_an_error",), "counts a refusal as an acknowledgement"),
    _u(13, F, "a silent robot: the fleet holds at the barrier for the tick deadline, the robot is taken out of the "
              "plan, the others get a new plan (new `plan_id`, `start_tick = k`); degraded exit 3",
       ("test_a_silent_robot_is_taken_out_of_the_plan",), "sends repair plans with `start_tick` 0"),
    _u(14, F, "`Done` is a claim, the camera is the proof: a `Done` the camera contradicts is no success",
       ("test_a_done_the_camera_contradicts_is_no_success",), "believes every `Done`"),
    _u(15, K, "drops garbage, wrong types, wrong versions and another robot's messages on a robot's keys; resent "
              "states and `Done` change nothing", ("test_garbage_on_robot_keys_is_dropped",),
       "accepts a message naming another robot than its key"),
    _u(16, P, "resends a plan not acknowledged within 2 s (same `plan_id`, same path)",
       ("test_an_unacknowledged_plan_is_resent",), "resends only after 6 s"),
)


def rules(side: str | None = None) -> list[Rule]:
    return [r for r in RULES if side is None or r.side == side]


def rule(rule_id: str) -> Rule:
    for r in RULES:
        if r.id == rule_id:
            return r
    raise KeyError(f"no rule {rule_id!r}: the ids are {', '.join(r.id for r in RULES)}")


def _cell(text: str) -> str:
    return text.replace("|", "\\|")


def markdown() -> str:
    """docs/conformance-rules.md."""
    out = ["# Conformance rules",
           "",
           "Every rule of [protocol.md](protocol.md) that a robot (R) or a UAV (U) must keep, the section it comes",
           "from, the conformance tests that check it (in `conformance/test_robot_conformance.py` and",
           "`conformance/test_uav_conformance.py`), and the mutant that proves they do: a copy of our own robot or",
           "UAV with that one rule broken (`python -m conformance.mutants robot|uav --break ID ...`), which the",
           "listed tests must fail (`tests/test_conformance_mutants.py` runs them all in CI).",
           "",
           "Generated from `conformance/rules.py` (`python -m conformance.rules --write`); "
           "`uav-robots conformance --list-rules` prints it.",
           ""]
    for side, title in (("robot", "Robots"), ("uav", "UAVs")):
        out += [f"## {title}", "", "| id | section | rule | tests | mutant |", "|---|---|---|---|---|"]
        for r in rules(side):
            tests = "<br>".join(f"`{t}`" for t in r.tests)
            out.append(f"| {r.id} | {r.section} | {_cell(r.text)} | {tests} | {_cell(r.mutant)} |")
        out.append("")
    return "\n".join(out)


def text_table(side: str | None = None) -> str:
    """The table for a terminal."""
    lines = []
    for r in rules(side):
        lines.append(f"{r.id:4} [{r.section}] {r.text}")
        lines.append(f"     tests: {', '.join(r.tests)}; mutant: {r.mutant}")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m conformance.rules", description=__doc__.splitlines()[0])
    p.add_argument("--write", action="store_true", help=f"write {DOC.name}")
    p.add_argument("--check", action="store_true", help=f"exit 1 if {DOC.name} is not current")
    args = p.parse_args(argv)
    if args.write:
        DOC.write_text(markdown())
        return 0
    if args.check:
        current = DOC.exists() and DOC.read_text() == markdown()
        if not current:
            print(f"error: {DOC.name} is not current: run python -m conformance.rules --write", file=sys.stderr)
        return 0 if current else 1
    print(text_table())
    return 0


if __name__ == "__main__":
    sys.exit(main())
