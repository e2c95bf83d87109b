"""The rules a robot must keep (R1..), each with the tests of the robot suite that check it and its mutant."""
from __future__ import annotations

from .rule import E, K, M, P, S, Rule


def _r(n: int, section: str, text: str, tests: tuple[str, ...], mutant: str, since: int = 1) -> Rule:
    return Rule(f"R{n}", section, text, tests, mutant, since)


# Tests that check several rules.
MALFORMED = "test_a_malformed_plan_is_refused"
FOLLOW = "test_ticks_follow_the_plan_and_done_is_raised_once"
REFUSED = "test_refused_move_leaves_the_robot_in_place"
NO_ANSWER = "test_no_answer_from_the_world_is_an_error_state"
AFTER_ERROR = "test_after_an_error_tick_the_robot_goes_on_from_its_last_known_cell"
AHEAD = "test_a_robot_moving_ahead_puts_each_move_before_what_the_uav_waits_for"
POOL = "test_a_pool_keeps_each_robots_contract"
BATCH = "test_a_pool_told_to_batch_reports_each_robots_state_of_the_tick"
POOL_AHEAD = "test_a_pool_moving_ahead_puts_one_move_per_plan_it_holds"

ROBOT_RULES: tuple[Rule, ...] = (
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
)
