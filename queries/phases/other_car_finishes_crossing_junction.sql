-- phase: other_car_finishes_crossing_junction (unprotected_left_turn_with_yield_and_traffic_light, phase 3)
-- grain: one row per (drive_id, ego_id, ego_passage, actor_id, actor_passage, frame) of unprotected_left_turn_frames:
--        the phase contract (docs/scenarios.md)
-- reads: scenario_frames (phases/unprotected_left_turn_frames.sql)
-- params: none
--
-- holds = all of: actor_kind_ok, ego_turns_left, ego_yields, actor_finishing, actor_reaches_junction_end. Each
-- condition is defined in unprotected_left_turn_frames.sql and docs/semantics.md; segment = 0 (the phase is not
-- cut by the ego's lane runs).
select
    0 as segment,
    actor_kind_ok and ego_turns_left and ego_yields and actor_finishing and actor_reaches_junction_end as holds,
    *
from scenario_frames
