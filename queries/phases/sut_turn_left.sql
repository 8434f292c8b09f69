-- phase: sut_turn_left (unprotected_left_turn_with_yield_and_traffic_light, phase 4)
-- grain: one row per (drive_id, ego_id, ego_passage, actor_id, actor_passage, frame) of unprotected_left_turn_frames:
--        the phase contract (docs/scenarios.md)
-- reads: scenario_frames (phases/unprotected_left_turn_frames.sql)
-- params: none
--
-- holds = all of: actor_kind_ok, ego_turns_left, ego_turning. Each condition is defined in
-- unprotected_left_turn_frames.sql and docs/semantics.md; segment = 0 (the phase is not cut by the ego's lane
-- runs).
select
    0 as segment,
    actor_kind_ok and ego_turns_left and ego_turning as holds,
    *
from scenario_frames
