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

DOC = Path(__file__).resolve().parents[1] / "docs" / "conformance-rules.md"


@dataclass(frozen=True)
class Rule:
    id: str                 # R<n> (robots) or U<n> (UAVs)
    section: str            # the docs/protocol.md section it comes from
    text: str               # the rule, as an implementer reads it
    tests: tuple[str, ...]  # test functions (pytest -k names) of the side's suite that check it
    mutant: str             # how the rule's mutant (conformance.mutants) breaks it
    since: int = 1          # the protocol version that introduced it (docs/protocol.md, Versioning)

    @property
    def side(self) -> str:
        return "robot" if self.id.startswith("R") else "uav"


def _r(n: int, section: str, text: str, tests: tuple[str, ...], mutant: str, since: int = 1) -> Rule:
    return Rule(f"R{n}", section, text, tests, mutant, since)


def _u(n: int, section: str, text: str, tests: tuple[str, ...], mutant: str, since: int = 1) -> Rule:
    return Rule(f"U{n}", section, text, tests, mutant, since)


S, K, M, P, F, E = ("Startup order", "Keys", "Messages", "Plans and ticks", "Faults and recovery", "End of mission")
W = "Timeouts and waits"
MALFORMED = "test_a_malformed_plan_is_refused"
FOLLOW = "test_ticks_follow_the_plan_and_done_is_raised_once"
REFUSED = "test_refused_move_leaves_the_robot_in_place"
NO_ANSWER = "test_no_answer_from_the_world_is_an_error_state"
AFTER_ERROR = "test_after_an_error_tick_the_robot_goes_on_from_its_last_known_cell"
AHEAD = "test_a_robot_moving_ahead_puts_each_move_before_what_the_uav_waits_for"
POOL = "test_a_pool_keeps_each_robots_contract"
BATCH = "test_a_pool_told_to_batch_reports_each_robots_state_of_the_tick"
POOL_AHEAD = "test_a_pool_moving_ahead_puts_one_move_per_plan_it_holds"

RULES: tuple[Rule, ...] = (
    # ------------------------------------------------------------ robots
    _r(1, S, "declares its token `alive/robot/<id>` while it runs, and again when restarted on the same id",
       ("test_liveliness_token_appears", "test_restart_gets_a_fresh_token"), "never declares its token"),
    _r(2, S, "subscribes to its plan key, `tick` (moving ahead: `world/judged/<ids>`) and `mission/end` before it "
             "declares its token: a plan or a `MissionEnd` put the moment the token is seen is received",
       ("test_valid_plan_is_acknowledged", "test_a_mission_end_put_as_the_token_appears_is_received"),
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
       "ignores `Plan.connectivity` (uses its own 4)", since=2),
    _r(11, P, "acknowledges a plan resent with the same `plan_id` (and path) again", ("test_a_resent_plan_is_acknowledged_again",),
       "answers a plan id only once"),
    _r(12, P, "refuses a different path under a `plan_id` it already holds",
       ("test_another_path_under_the_same_plan_id_is_refused",), "takes the new path"),
    _r(13, P, "a refusal is `ok: false` with a one-line, non-empty `error`", (MALFORMED,),
       "refuses with an empty `error`"),
    _r(14, M, "drops a message that does not decode, has another `type` or a wrong `v`: no ack for such a plan (not "
              "even `ok: false`), no move on such a tick, no crash, its state kept",
       ("test_garbage_and_wrong_versions_do_not_crash_it",), "answers an undecodable plan with `ok: false`"),
    _r(15, P, "refuses a plan whose `start_tick` is above 0 and below the last tick it executed",
       ("test_a_repair_plan_for_a_past_tick_is_refused",), "takes a plan for a past tick", since=2),
    _r(16, P, "a repair plan (`start_tick > 0`): `path[0]` is its cell whatever it believed, `path[i]` is its cell at "
              "tick `start_tick + i`", ("test_a_repair_plan_starts_at_its_tick_and_is_switched_to_at_once",),
       "checks a repair plan against its own belief", since=2),
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
       (NO_ANSWER,), "publishes nothing when the world is silent"),
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
              "message; a pool's `MoveBatch` queries, its `StateBatch`es and its `MoveAhead`s each with a counter "
              "of their own", ("test_sequence_numbers_count_by_one_from_1", POOL, BATCH, AHEAD),
       "never increments `seq`"),
    _r(30, P, "a pool (one process hosting several robots) keeps each robot's rules and asks one query a tick for "
              "all its robots that ask (a `MoveBatch`; a `MoveRequest` when only one asks): one move per robot, "
              "states on each robot's key, each robot's own `seq` counter", (POOL,),
       "a pool asks a `MoveRequest` for each of its robots"),
    _r(31, E, "exits (code 0) within 5 s of `MissionEnd`, withdrawing its token", ("test_exits_on_mission_end",),
       "ignores `MissionEnd`"),
    _r(32, E, "exits (code 0) within 5 s of SIGTERM", ("test_exits_on_sigterm",), "ignores SIGTERM"),
    _r(33, E, "exits within 5 s when `alive/uav` disappears after having been seen",
       ("test_exits_when_the_uav_goes_away",), "ignores the UAV's token"),
    _r(34, P, "moving ahead (optional): puts the move of a plan's first tick before its `PlanAck` and the move of "
              "tick k+1 before its state of k, as `MoveAhead` on `P/world/ahead/<ids>` naming its plan; takes its "
              "cell from the world's `MovesJudged`, asks no query; a replan puts a new move for the next tick",
       (AHEAD,), "puts its state of tick k before its move of k+1", since=2),
    _r(35, K, "asks its moves on `P/world/move/<ids>`, `<ids>` its own ids, not on the plain `P/world/move` that "
              "access control leaves unreachable; a pool on its own ids in canonical form (`7-8`, however its "
              "`--ids` spelled them)", ("test_moves_are_asked_on_the_key_naming_the_robot",
                                        "test_a_pool_asks_on_the_key_naming_its_robots"),
       "asks on the plain `P/world/move`", since=2),
    _r(36, M, "a pool told `batch_states` may put one `StateBatch` a tick on `P/robots/<ids>/states` (its own ids, "
              "canonical) instead of its robots' `RobotState`s; either way each robot's state of the tick, once",
       (BATCH,), "puts its batches on a key naming its first robot only", since=2),
    _r(37, P, "a pool moving ahead (optional) puts one `MoveAhead` per `plan_id` its robots hold, on "
              "`P/world/ahead/<ids>` (its own ids, canonical): a robot holding another plan than the tick's stays",
       (POOL_AHEAD,), "puts every robot's move under the first robot's plan", since=2),
    # Each sentence of docs/protocol.md that says what a robot must, does or never does, and that the
    # rules above did not yet name (an independent robot broke them one at a time and passed).
    _r(38, M, "everything it puts or asks is one JSON object in UTF-8 without a byte-order mark: `type` its "
              "message, `v: 1`, each key once, and it decodes (types and limits)",
       ("test_everything_it_sends_is_one_well_formed_message",), "writes `seq` twice in its states"),
    _r(39, K, "every put uses congestion control BLOCK (QoS)", ("test_every_put_uses_congestion_control_block",),
       "puts its states with DROP"),
    _r(40, K, "waits for the world's answer to a move up to its move timeout, 5 s (longer than the world's 2 s "
              "batch timeout): an answer 3 s late is taken", ("test_a_late_answer_within_the_move_timeout_is_taken",),
       "waits 1 s"),
    _r(41, P, "asks the world once a tick, also when no answer comes", (NO_ANSWER,),
       "asks again when the world did not answer"),
    _r(42, P, "a query that ends without a reply (no world serves the key) is no answer at once: the `error` "
              "state comes without waiting out the move timeout",
       ("test_a_query_that_ends_without_a_reply_is_no_answer_at_once",), "waits out its move timeout", since=2),
    _r(43, P, "an answer for another tick or another robot is no answer: an `error` state at its last known cell",
       ("test_an_answer_for_another_tick_or_robot_is_no_answer",), "takes an answer for another tick", since=2),
    _r(44, P, "a pool: a robot its `MoveBatchResult` has no entry for gets an `error` state, the others take "
              "their entries; an entry for a robot it did not ask for is ignored",
       ("test_a_batch_answer_missing_or_adding_robots",), "takes an entry for a robot it did not ask for",
       since=2),
    _r(45, M, "takes a message with fields it does not know (whatever their value, JSON) and without the fields "
              "that have a default", ("test_unknown_fields_are_ignored_and_defaults_may_be_left_out",),
       "drops a message with a field it does not know"),
    _r(46, M, "drops a plan or a tick that breaks the Types (a `bool` written `1`, an `int` written `2.0` or "
              "`true`, `NaN`, a lone surrogate): no ack, no move",
       ("test_a_message_breaking_the_types_is_dropped",), "takes `2.0` for an int", since=2),
    _r(47, M, "drops a plan or a tick that breaks a limit (a cell beyond 16,383, a `plan_id` over 4,096 "
              "characters, a path over 100,001 cells, nesting over 32 levels, a payload over 8 MiB, `Tick.k` 0, "
              "a robot id over 9,999,999, `connectivity` 6): no ack, no move",
       ("test_a_message_breaking_a_limit_is_dropped",), "takes cells beyond 16,383 (clipped)", since=2),
    _r(48, P, "a plan without `start_tick` (or 0) counts from the highest tick it has seen, ticks heard while "
              "it held no plan included", ("test_a_plan_counts_from_the_highest_tick_seen",),
       "counts it from tick 0"),
    _r(49, P, "a robot that holds no plan asks nothing and publishes no state on a tick",
       ("test_a_robot_without_a_plan_asks_nothing",), "asks to stay at (0, 0) and reports it", since=2),
    _r(50, P, "until the world's first answer it accepts any `path[0]`, a second plan before tick 1 included",
       ("test_a_second_plan_before_tick_1_may_start_anywhere",), "checks a second plan against the first's start",
       since=2),
    _r(51, P, "a `plan_id` it held before (not the one it holds) is not remembered: a new plan",
       ("test_a_plan_id_held_before_is_a_new_plan",), "remembers every plan id it held", since=2),
    _r(52, M, "on a tick naming another plan it keeps its status: `ready` while it has executed no tick of its "
              "plan, `done` on its goal", ("test_a_tick_for_another_plan_keeps_the_status",),
       "reports `stepping` on such a tick", since=2),
    _r(53, M, "a refused move is no error: its state has the world's cell, its status after the tick "
              "(`stepping`; `done` once the plan is over and it stands on its goal) and the world's `reason` in "
              "`error`", ("test_a_refused_move_is_no_error_and_carries_the_worlds_reason",),
       "reports status `error` after a refused move", since=2),
    _r(54, M, "`error` is the status of that tick's state only: its next state carries its own status again",
       (AFTER_ERROR,), "keeps status `error` after an error tick", since=2),
    _r(55, P, "an `error` tick counts as executed: `Tick(k)` resent is ignored, `Tick(k+1)` is asked from its "
              "last known cell", (AFTER_ERROR,), "executes `Tick(k)` again after an error on it", since=2),
    _r(56, P, "`Done` comes right after the state of the tick at which the plan is over and it stands on its goal",
       ("test_done_follows_the_state_of_its_tick",), "puts `Done` before that state", since=2),
    _r(57, P, "a one-cell plan's `Done` comes at its first tick, never at the acknowledgement",
       ("test_a_one_cell_plan_is_done_at_its_first_tick",), "raises `Done` at the acknowledgement", since=2),
    _r(58, P, "never raises `Done` on a tick naming another plan", ("test_no_done_on_a_tick_naming_another_plan",),
       "raises `Done` on a tick naming another plan", since=2),
    _r(59, P, "a plan resent under the `plan_id` it holds raises no second `Done`; a plan with a new id does",
       ("test_done_once_per_plan_and_again_for_a_new_one",), "raises `Done` again for a resent plan"),
    _r(60, M, "pushed off its goal after it arrived, it reports `stepping` (and no new `Done`) until it stands "
              "there again", ("test_pushed_off_its_goal_it_is_stepping_again",), "stays `done` off its goal",
       since=2),
    _r(61, K, "drops what comes on a key whose robot id is not written canonically (`robot/007/plan` names no "
              "robot)", ("test_a_plan_on_a_non_canonical_id_key_is_dropped",
                         "test_a_pool_drops_a_plan_on_a_non_canonical_id_key"),
       "a pool reads the id of its plan keys with `int()`", since=2),
    _r(62, M, "a pool puts each robot's `RobotState` unless the `Tick` says `batch_states` (a UAV that does not "
              "say so reads no `StateBatch`)", ("test_a_pool_not_told_to_batch_puts_each_robots_state",),
       "batches without being told", since=2),
    _r(63, P, "moving ahead: a plan resent under the `plan_id` it holds puts the `MoveAhead` of the next tick "
              "again, before the repeated `PlanAck`",
       ("test_a_robot_moving_ahead_puts_its_move_again_for_a_resent_plan",), "puts no move for a resent plan",
       since=2),
    _r(64, P, "moving ahead: a `MovesJudged` for a tick it already took is ignored (no state, no move)",
       ("test_a_robot_moving_ahead_ignores_a_judgement_it_took",), "takes a `MovesJudged` again", since=2),
    _r(65, P, "moving ahead: a robot without a plan puts no move",
       ("test_a_pool_moving_ahead_puts_no_move_for_a_robot_without_a_plan",),
       "puts a move for every robot of the pool", since=2),
    _r(66, E, "exits (code 0) within 5 s of SIGINT", ("test_exits_on_sigint",), "ignores SIGINT"),
    _r(67, E, "does not exit while it has not seen the UAV's token: it serves plans before",
       ("test_serves_before_it_has_seen_the_uav",), "exits when no UAV token is up at its start"),
    _r(68, E, "exits within 5 s of `MissionEnd` while a move query waits for its answer: the query is abandoned, "
              "no state for its tick", ("test_exits_with_a_move_query_pending",),
       "waits for its pending move query before it exits", since=2),
    _r(69, E, "a `MissionEnd` that does not decode is dropped: no exit", ("test_an_undecodable_mission_end_is_dropped",),
       "exits on anything put on `mission/end`"),
    _r(70, S, "waits for a router at start (up to 20 s, then exits 1 with one line; only the wait is checked): "
              "a router that comes up 2 s after it started is joined", ("test_waits_for_a_router_at_start",),
       "gives up at once without a router", since=2),
    _r(71, M, "states the protocol version it keeps in every `PlanAck` (`protocol: 2` for this document)",
       ("test_every_plan_ack_states_the_protocol_it_keeps",), "states no `protocol`", since=2),
    _r(72, P, "moving ahead: reports nothing for a tick whose `MovesJudged` never came (no state of its own "
              "making; the UAV's tick deadline calls it stalled)",
       ("test_a_robot_moving_ahead_reports_nothing_without_a_judgement",),
       "reads `P/tick` too and reports an error state when no judgement came", since=2),
    _r(73, M, "a flood of messages it drops costs at most one warning line a second, each on one line",
       ("test_dropped_messages_cost_one_warning_line_a_second",), "warns once per dropped message", since=2),
    _r(74, M, "does not act on `seq`: a plan or tick with a lower or repeated `seq` is taken like any other "
              "(the tick number `k` is the mission's clock)", ("test_seq_is_not_acted_on",),
       "drops a message whose `seq` is not above the last one's", since=2),
    # ------------------------------------------------------------ UAVs
    # What a UAV must do, each checked from outside: what it puts, what the world's record and its
    # vehicle show, its exit. Missions of the suite: clean, noisy, faults, degraded, refused, and
    # missions that end early; each rule's tests name the one mission its mutant must fail.
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
    _u(9, M, "numbers what it sends with one counter (plans, ticks, status, events, mission end, queries): `Tick` "
             "numbers increase, no two messages share one",
       ("test_uav_sequence_numbers_increase",), "never increments `seq`"),
    _u(10, E, "exactly one `MissionEnd(completed=true)`, after the last tick; exit 0, no traceback",
       ("test_mission_ends_completed_and_the_uav_exits_0",), "puts `MissionEnd` twice"),
    _u(11, E, "lands its vehicle (disarmed, on the ground) after the mission", ("test_the_vehicle_took_off_and_landed",),
       "never lands"),
    _u(12, F, "a refused first plan (`ok: false`): no tick, `MissionEnd(completed=false)`, its token withdrawn, exit 1 "
              "with a line on stderr naming the robot, within the tick timeout + 10 s",
       ("test_a_refused_plan_ends_the_mission_with_an_error",), "counts a refusal as an acknowledgement"),
    _u(13, F, "a silent robot: the fleet holds at the barrier for the tick deadline (not less), the robot is taken "
              "out of the plan, the others get a new plan (new `plan_id`, `start_tick = k`); degraded exit 3",
       ("test_a_silent_robot_is_taken_out_of_the_plan",), "sends repair plans with `start_tick` 0", since=2),
    _u(14, F, "`Done` is a claim, the camera is the proof: a `Done` the camera contradicts is an event (a "
              "`MissionEvent` naming the robot) and no success (exit 1 or 3)",
       ("test_a_done_the_camera_contradicts_is_no_success",), "believes every `Done`", since=2),
    _u(15, K, "drops garbage, wrong types, wrong versions and another robot's messages on a robot's keys; resent "
              "states and `Done` change nothing", ("test_garbage_on_robot_keys_is_dropped",),
       "accepts a message naming another robot than its key"),
    _u(16, P, "puts a plan not acknowledged again every 2 s (same `plan_id`, same path)",
       ("test_an_unacknowledged_plan_is_resent",), "resends only after 6 s", since=2),
    _u(17, F, "every plan it puts, each repair included, is executable from the cells its robots really stood on at "
              "its `start_tick` (the world's record): adjacent free cells, off the cells of the robots out of it, "
              "each ending on a goal marker of its own, no vertex, swap or crossing conflict; a repair goes to every "
              "robot still working that can reach an open goal",
       ("test_every_repair_plan_is_executable_and_reaches_every_working_robot",),
       "leaves the highest working robot out of every repair", since=2),
    _u(18, F, "a robot whose `alive/robot/<id>` token vanishes is lost: no further tick of the plan (even with that "
              "tick's barrier complete); a repair from that tick without it, and no plan to it again",
       ("test_a_lost_robot_is_taken_out_at_once",), "ignores a robot's token vanishing", since=2),
    _u(19, F, "a `RobotState` with `status: \"error\"` for tick k: the fleet holds at k, a repair from k leaves the "
              "robot out", ("test_a_robot_in_error_is_taken_out_of_the_plan",),
       "takes an `error` state for a `stepping` one", since=2),
    _u(20, F, "a robot reporting a cell other than its plan's for tick k (a deviation): the fleet holds at k, a repair "
              "from k plans it from where it stands", ("test_a_deviation_is_repaired_from_where_the_robot_stands",),
       "believes every robot is on its plan's cell, whatever its state says", since=2),
    _u(21, F, "a robot taken out of the plan that shows life again (a state: it stalled past the tick deadline and "
              "came back) rejoins: a repair gives it a plan, and the mission completes with it (exit 0)",
       ("test_a_stalled_robot_that_comes_back_rejoins",),
       "never takes a robot back", since=2),
    _u(22, F, "a robot that keeps failing (a fault named by each repair, never shown on its planned cell "
              "between, by an image or two moves kept in a row: 3 strikes) is quarantined, out of the plan for good: a bounded number of plans names it, the "
              "others finish, their repairs not counted against the mission; `MissionEnd(completed=true)` and exit 3 "
              "(degraded)",
       ("test_a_robot_that_keeps_failing_is_quarantined_and_the_rest_finish",),
       "gives up the whole mission at its third repair", since=2),
    _u(23, P, "drops a state for a tick after the last `Tick` it put: it reports nothing for the barrier of that "
              "tick (nor an error)", ("test_a_state_for_a_tick_not_yet_put_reports_nothing",),
       "takes a state for any tick", since=2),
    _u(24, M, "drops the entries of a `StateBatch` for robots its key does not name",
       ("test_state_batch_entries_for_robots_the_key_does_not_name_are_dropped",),
       "takes every entry of a `StateBatch`", since=2),
    _u(25, S, "keeps `alive/uav` up from before its first plan until after `MissionEnd`, without a gap (robots "
              "exit when it disappears)", ("test_the_uav_token_stays_up_for_the_whole_mission",),
       "withdraws and declares `alive/uav` again before dispatching"),
    _u(26, E, "a robot that arrives and raises no `Done`: after the last tick the UAV waits at most 5 s for `Done` "
              "flags, then its camera decides: seen on its goal, it has arrived (exit 0)",
       ("test_a_robot_that_never_raises_done_is_verified_by_the_camera",),
       "counts a robot without a `Done` as not arrived", since=2),
    _u(27, F, "a mode of its vehicle it did not command (RTL from a ground station) ends the mission as aborted: "
              "no further tick, an event, `MissionEnd(completed=false)`, exit 1, landed",
       ("test_a_mode_the_uav_did_not_command_ends_the_mission",), "ignores its vehicle's modes", since=2),
    _u(28, W, "no `alive/world` within 30 s: it ends the mission (exit 1, a line naming the world, "
              "`MissionEnd(completed=false)`, its token withdrawn)", ("test_a_uav_without_a_world_ends_the_mission",),
       "waits for the world for ever", since=2),
    _u(29, W, "`world/info` answered with nothing, or with garbage: it ends the mission within 10 s (exit 1, a line "
              "naming the query)", ("test_a_world_that_does_not_answer_its_info_ends_the_mission",),
       "asks `world/info` again until an answer decodes"),
    _u(30, W, "a robot whose token never comes up: no plan is put, the mission ends within 30 s of its last "
              "phase change (exit 1, a line naming the missing robot)",
       ("test_a_robot_that_never_comes_up_ends_the_mission",),
       "waits for every robot's token for ever", since=2),
    _u(31, W, "a repair plan not acknowledged: put again every 2 s, then after at most 30 s the robot is taken out "
              "and the others go on (no abort)", ("test_an_unacknowledged_repair_is_put_again_and_then_given_up",),
       "ends the mission when a repair goes unacknowledged", since=2),
    _u(32, K, "`mission/status`: the phases in the document's order, `executing` every 10 ticks with `tick`, "
              "`ticks`, `done` and `robots` (the fleet), `land` last",
       ("test_the_status_follows_the_mission_phases",), "puts no `executing` status after tick 0"),
    _u(33, K, "`mission/event`: each fault is a `MissionEvent` naming the robot, put as it happens (before the next "
              "tick)", ("test_each_fault_is_an_event_as_it_happens",), "publishes no `MissionEvent`", since=2),
    _u(34, K, "`uav/pose`: about 5 a second (at least 2, no gap over 2 s) from before the take-off until landed",
       ("test_the_pose_stream_covers_the_flight",), "puts a pose every 2 s", since=2),
    _u(35, K, "`uav/frame`: its images as JPEG of at most 640 px, the image's pose and time kept and its "
              "intrinsics scaled, before `MissionEnd`", ("test_the_frame_stream_shows_the_uavs_images",),
       "publishes its images at full size, PNG", since=2),
    _u(36, F, "an image taken during execution shows a settled floor: the fleet holds at a tick boundary and the "
              "robots still working have finished the tick (a fresh look after a robot vanished mid-tick included)",
       ("test_images_during_execution_are_taken_while_the_fleet_holds",),
       "looks at once when a robot is lost, the others mid-tick", since=2),
    _u(37, E, "puts no `Tick` and no `Plan` after `MissionEnd`", ("test_nothing_is_put_to_the_robots_after_mission_end",),
       "puts the last plan again after `MissionEnd`", since=2),
    _u(38, E, "an aborted mission's `MissionEnd(completed=false)` says why: its `reason` names what failed (the "
              "robot that refused its plan)", ("test_an_aborted_mission_end_says_why",),
       "ends with an empty `reason`", since=2),
)


# What docs/protocol.md asks of a robot that the suite does not check, and why (side, section, what, why).
UNCHECKED: tuple[tuple[str, str, str, str], ...] = (
    ("robot", S, "without a router for 20 s it exits 1 with one line",
     "it takes 20 s; R70 checks the wait itself"),
    ("robot", K, "queries use Zenoh's default options (target best matching, consolidation auto)",
     "a queryable is not told the options of the query it answers"),
    ("robot", M, "a gap in the ticks is logged; a last line at exit says how many warnings were held back",
     "the text of a log line is the implementation's own"),
    ("robot", "Timeouts and waits", "it waits for the UAV, a plan or a tick as long as it runs",
     "no bounded test can tell forever from long; R67 checks it waits for a UAV not yet seen"),
    ("robot", "Security", "its session opens with its own certificate (`robot-<id>`, `robots-<ids>`)",
     "the suite's router has no TLS; `tests/test_secure.py` checks ours"),
    ("uav", E, "only a `Done` whose `tick` is after the current plan's `start_tick` counts for that plan",
     "the camera decides either way, U14 and U26: a stale `Done` only changes how long the UAV waits before it looks"),
    ("uav", W, "an answer from `world/camera` within 30 s and from `world/record` within 10 s",
     "the suite's world is ours and answers both; U29 checks the same bound on `world/info`"),
    ("uav", W, "robots still coming up are waited for at most 120 s in all; after an abort the landing 60 s",
     "they take minutes; U30 checks the 30 s without a robot coming up, U11 and the aborts that it lands"),
    ("uav", F, "how often it takes monitoring images (`--monitor-every`, automatically at most 20 % of the time)",
     "the UAV's own choice; U36 checks that each image shows a settled floor"),
    ("uav", K, "`uav/frame` carries only the newest image when images come faster than they are encoded",
     "a subscriber cannot tell a skipped image from a lost put"),
)


def rules(side: str | None = None) -> list[Rule]:
    return [r for r in RULES if side is None or r.side == side]


def since_of_test(side: str, test: str) -> int:
    """The protocol version a test needs: the newest of the rules it checks (1 for a test no rule names).

    A robot that states an older version in its `PlanAck` is not held to the rules that came after it,
    so a test that checks one of them is skipped for it; each rule has a test of its own version."""
    return max((r.since for r in rules(side) if test in r.tests), default=1)


def newer_rules(side: str, version: int) -> list[Rule]:
    """The rules of `side` that an implementation keeping protocol `version` is not held to."""
    return [r for r in rules(side) if r.since > version]


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
           "from, the conformance tests that check it (in `conformance/test_robot_*.py` and",
           "`conformance/test_uav_*.py`), and the mutant that proves they do: a copy of our own robot or",
           "UAV with that one rule broken (`python -m conformance.mutants robot|uav --break ID ...`), which the",
           "listed tests must fail (`tests/test_conformance_mutants.py` runs them all in CI). *Since* is the",
           "protocol version that introduced the rule: a robot whose `PlanAck` states an older `protocol` (none",
           "stated: 1) is not held to it, and the suite says so (docs/protocol.md, Versioning).",
           "",
           "Generated from `conformance/rules.py` (`python -m conformance.rules --write`); "
           "`uav-robots conformance --list-rules` prints it.",
           ""]
    for side, title in (("robot", "Robots"), ("uav", "UAVs")):
        out += [f"## {title}", "", "| id | since | section | rule | tests | mutant |", "|---|---|---|---|---|---|"]
        for r in rules(side):
            tests = "<br>".join(f"`{t}`" for t in r.tests)
            out.append(f"| {r.id} | {r.since} | {r.section} | {_cell(r.text)} | {tests} | {_cell(r.mutant)} |")
        out.append("")
        unchecked = [u for u in UNCHECKED if u[0] == side]
        if unchecked:
            out += ["Not checked, and why:", ""]
            out += [f"- {section}: {what} ({why})" for _side, section, what, why in unchecked]
            out.append("")
    return "\n".join(out)


def text_table(side: str | None = None) -> str:
    """The table for a terminal."""
    lines = []
    for r in rules(side):
        lines.append(f"{r.id:4} [{r.section}; since protocol {r.since}] {r.text}")
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
