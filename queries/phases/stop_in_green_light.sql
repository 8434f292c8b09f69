-- phase: stop_in_green_light (unprotected_left_turn_with_yield_and_traffic_light, phase 1)
-- grain: one row per (drive_id, ego_id, ego_passage, actor_id, actor_passage, frame) of unprotected_left_turn_frames:
--        the phase contract (docs/scenarios.md)
-- reads: scenario_frames (phases/unprotected_left_turn_frames.sql)
-- params: none
--
-- holds = all of: actor_kind_ok, ego_turns_left, ego_near_junction_start, ego_has_stopped, light_in_range,
-- light_green, actor_approaching, ego_yields. Each condition is defined in
-- unprotected_left_turn_frames.sql and docs/semantics.md; segment = 0 (the phase is not cut by the ego's lane
-- runs).
select
    0 as segment,
    actor_kind_ok and ego_turns_left and ego_near_junction_start and ego_has_stopped and light_in_range and
        light_green and actor_approaching and ego_yields as holds,
    *
from scenario_frames
