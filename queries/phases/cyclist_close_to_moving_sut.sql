-- phase: cyclist_close_to_moving_sut
-- grain: one row per (drive_id, ego_id, actor_id, frame) for every actor that is not a vehicle kind (relations
--        keeps those within object_relation_range): the phase contract (docs/scenarios.md)
-- reads: relations
-- params: $sut_minimal_speed_mps, $min_distance_from_cyclist_m, $max_distance_from_cyclist_m
--
-- Conditions (holds = all of them):
--   ego_moving          the ego's speed >= sut_minimal_speed
--   actor_is_cyclist    the actor's kind is cyclist
--   distance_in_range   the closest box-to-box distance is in [min_distance_from_cyclist, max_distance_from_cyclist]
-- "The scenario should last at most max_phase_duration": the phase's max_duration (the scenario file); a longer
-- episode is cut into consecutive matches (docs/semantics.md, "Durations").
with

conditions as (
    select
        r.drive_id,
        r.ego_id,
        r.actor_id,
        r.drive_key,
        r.ego_key,
        r.actor_key,
        r.frame,
        r.t_s,
        0 as segment,
        coalesce(r.ego_speed_mps >= $sut_minimal_speed_mps, false) as ego_moving,
        r.actor_kind = 'cyclist' as actor_is_cyclist,
        r.box_distance_m >= $min_distance_from_cyclist_m
            and r.box_distance_m <= $max_distance_from_cyclist_m as distance_in_range,
        r.ego_speed_mps,
        r.actor_kind,
        r.box_distance_m
    from relations as r
    where r.actor_kind not in ('vehicle', 'truck', 'bus', 'trailer', 'motorcycle', 'emergency_vehicle')
)

-- holds is exactly the AND of the conditions above (logiq-sql lint checks it against the scenario file)
select
    *,
    ego_moving and actor_is_cyclist and distance_in_range as holds
from conditions
