-- phase: ego_side_of_npc (sut_cut_out, phase 2)
-- grain: one row per (drive_id, ego_id, actor_id, island): a maximal run of consecutive frames that begins
--        with the ego's lane change and in which the ego drives in a lane beside the actor's, at least
--        min_ego_on_side_of_npc_phase_duration long
-- reads: relations, ego_lanes, track_lanes
-- params: $kinds_csv, $lane_calculation_tolerance_length_m, $min_ego_on_side_of_npc_phase_duration_s
--
-- Per frame, all of:
--   actor    is of one of the kinds; its lane is beside the ego's lane (adjacent_side, from lane_neighbours:
--            robust to lane-id changes at segment boundaries), on the side opposite to the ego's lane change
--   ego      is more than lane_calculation_tolerance_length away from the actor's lane, and stays in the lane
--            run it entered with its lane change (a second lane change ends the phase)
-- The island must begin at the frame of the ego's lane change (ego_lanes.lane_change_side): "the Ego changes
-- lanes". The actor "continues driving in the same lane": had it changed lanes too, it would no longer be
-- beside the ego on that side, and the island ends. The match query keeps the first
-- max_ego_on_side_of_npc_phase_duration of it.
with

beside as (
    select
        r.drive_id,
        r.ego_id,
        r.actor_id,
        r.frame,
        r.t_s,
        el.lane_run,
        r.adjacent_side
    from relations as r
    inner join ego_lanes as el
        on r.drive_id = el.drive_id and r.ego_id = el.ego_id and r.frame = el.frame
    left join track_lanes as kept
        on r.drive_id = kept.drive_id and r.ego_id = kept.actor_id and r.frame = kept.frame
        and r.actor_lane_id = kept.lane_id
        and kept.dist_m <= $lane_calculation_tolerance_length_m
    where instr($kinds_csv, ',' || r.actor_kind || ',') > 0
        and r.adjacent_side is not null
        and kept.lane_id is null
),

islands as (
    select
        *,
        frame - row_number() over (
            partition by drive_id, ego_id, actor_id, lane_run, adjacent_side order by frame
        ) as island
    from beside
),

spans as (
    select
        drive_id,
        ego_id,
        actor_id,
        lane_run,
        adjacent_side,
        min(frame) as start_frame,
        max(frame) as end_frame,
        min(t_s) as start_s,
        max(t_s) as end_s
    from islands
    group by drive_id, ego_id, actor_id, lane_run, adjacent_side, island
    having max(t_s) - min(t_s) >= $min_ego_on_side_of_npc_phase_duration_s
)

select
    s.drive_id,
    s.ego_id,
    s.actor_id,
    s.start_frame,
    s.end_frame,
    s.start_s,
    s.end_s
from spans as s
inner join ego_lanes as change
    on s.drive_id = change.drive_id and s.ego_id = change.ego_id and s.start_frame = change.frame
where change.lane_change_side is not null
    and change.lane_change_side <> s.adjacent_side
