-- phase: actor_beside_ahead (cut_in_ahead_of_ego, phase 1; logiq_sql's own scenario, not a LogIQ page)
-- grain: one row per (drive_id, ego_id, actor_id, frame) at which the actor is ahead of the ego (dx_m > 0): the
--        phase contract (docs/scenarios.md)
-- reads: relations
-- params: $kinds_csv, $min_distance_from_sut_in_time_units_s, $max_distance_from_sut_in_time_units_s
--
-- Conditions (holds = all of them):
--   actor_kind_ok      the actor is of one of the kinds
--   actor_ahead        entirely ahead of the ego's front bumper (dx > 0 and lon_gap > 0)
--   actor_beside       the actor's lane is beside the ego's lane (adjacent_side, from lane_neighbours)
--   headway_in_range   time headway (gap / ego speed) in [min_distance_from_sut_in_time_units,
--                      max_distance_from_sut_in_time_units]
-- segment = the ego's lane run: the ego keeps its lane while the actor cuts in.
select
    r.drive_id,
    r.ego_id,
    r.actor_id,
    r.frame,
    r.t_s,
    r.lane_run as segment,
    instr($kinds_csv, ',' || r.actor_kind || ',') > 0 as actor_kind_ok,
    r.lon_gap_m > 0 as actor_ahead,
    r.adjacent_side is not null as actor_beside,
    coalesce(r.time_headway_s >= $min_distance_from_sut_in_time_units_s
        and r.time_headway_s <= $max_distance_from_sut_in_time_units_s, false) as headway_in_range,
    instr($kinds_csv, ',' || r.actor_kind || ',') > 0 and r.lon_gap_m > 0 and r.adjacent_side is not null
        and coalesce(r.time_headway_s >= $min_distance_from_sut_in_time_units_s
            and r.time_headway_s <= $max_distance_from_sut_in_time_units_s, false) as holds,
    r.actor_kind,
    r.lon_gap_m,
    r.adjacent_side,
    r.time_headway_s,
    r.ego_lane_id,
    r.actor_lane_id
from relations as r
where r.dx_m > 0
