"""The rules a UAV must keep (U1..), each with the tests of the UAV suite that check it and its mutant."""
from __future__ import annotations

from .rule import E, F, K, M, P, S, W, Rule


def _u(n: int, section: str, text: str, tests: tuple[str, ...], mutant: str, since: int = 1) -> Rule:
    return Rule(f"U{n}", section, text, tests, mutant, since)


# What a UAV must do, each checked from outside: what it puts, what the world's record and its
# vehicle show, its exit. Missions of the suite: clean, noisy, faults, degraded, refused, and
# missions that end early; each rule's tests name the one mission its mutant must fail.
UAV_RULES: tuple[Rule, ...] = (
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
