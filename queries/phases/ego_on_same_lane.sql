-- phase: ego_on_same_lane (sut_cut_out, phase 1)
-- grain: one row per (drive_id, ego_id, actor_id, island): a maximal run of consecutive frames in which the
--        ego follows the actor in the actor's lane, at least min_ego_on_same_lane_phase_duration long
-- reads: relations, ego_lanes, track_lanes
-- params: $kinds_csv, $min_distance_from_sut_in_time_units_s, $max_distance_from_sut_in_time_units_s,
--         $lane_calculation_tolerance_length_m, $min_ego_on_same_lane_phase_duration_s
--
-- Per frame, all of:
--   actor    is of one of the kinds and entirely ahead of the ego's front bumper (dx > 0, lon_gap > 0), at a
--            time headway (gap / ego speed) in [min_distance_from_sut_in_time_units,
--            max_distance_from_sut_in_time_units]
--   nearest  it is the nearest road user (any kind) ahead of the ego in that lane: the one the ego follows
--   lane     the ego is in the actor's lane: the same lane or its direct successor/predecessor, or the ego's
--            centre is still within lane_calculation_tolerance_length of the actor's lane polygon (keep_lane
--            tolerance: while the ego drifts across the line it still follows the actor)
-- Islands are cut at the ego's lane changes (lane_run), so the phase ends at the latest when the ego has left
-- the lane; the match query keeps the last max_ego_on_same_lane_phase_duration of it.
with

ahead as (
    select
        r.drive_id,
        r.ego_id,
        r.actor_id,
        r.frame,
        r.t_s,
        r.actor_kind,
        r.time_headway_s,
        el.lane_run,
        -- the actor the ego follows is the road user right ahead of it in the lane
        row_number() over (partition by r.drive_id, r.ego_id, r.frame order by r.lon_gap_m, r.actor_id) as rank_ahead
    from relations as r
    inner join ego_lanes as el
        on r.drive_id = el.drive_id and r.ego_id = el.ego_id and r.frame = el.frame
    left join track_lanes as kept
        on r.drive_id = kept.drive_id and r.ego_id = kept.actor_id and r.frame = kept.frame
        and r.actor_lane_id = kept.lane_id
        and kept.dist_m <= $lane_calculation_tolerance_length_m
    where r.dx_m > 0
        and r.lon_gap_m > 0
        and (r.same_lane or kept.lane_id is not null)
),

islands as (
    select
        *,
        frame - row_number() over (partition by drive_id, ego_id, actor_id, lane_run order by frame) as island
    from ahead
    where rank_ahead = 1
        and instr($kinds_csv, ',' || actor_kind || ',') > 0
        and time_headway_s >= $min_distance_from_sut_in_time_units_s
        and time_headway_s <= $max_distance_from_sut_in_time_units_s
)

select
    drive_id,
    ego_id,
    actor_id,
    min(frame) as start_frame,
    max(frame) as end_frame,
    min(t_s) as start_s,
    max(t_s) as end_s
from islands
group by drive_id, ego_id, actor_id, lane_run, island
having max(t_s) - min(t_s) >= $min_ego_on_same_lane_phase_duration_s
