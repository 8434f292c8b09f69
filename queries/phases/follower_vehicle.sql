-- phase: follower_vehicle
-- grain: one row per (drive_id, ego_id, actor_id, island): a maximal run of consecutive frames in which the
--        actor follows the ego, at least min_scenario_duration long
-- reads: relations, ego_lanes
-- params: $kinds_csv, $min_distance_from_sut_in_time_units_s, $max_distance_from_sut_in_time_units_s,
--         $same_road_limit_s, $min_scenario_duration_s
--
-- Per frame, all of:
--   ego      is in a lane; the phase never spans a lane change of the ego (islands are cut per lane run)
--   actor    is of one of the kinds, entirely behind the ego's rear bumper (dx < 0 and lon_gap > 0: an actor
--            alongside, or overlapping the ego, is not following it), with a time headway (gap / actor speed) in
--            [min_distance_from_sut_in_time_units, max_distance_from_sut_in_time_units]
--   nearest  it is the nearest road user (any kind) behind the ego in that lane: the one that follows the ego;
--            a car behind it follows it, not the ego
--   lane     the actor's lane is the ego's lane or its direct predecessor/successor (same_lane), or a lane the
--            ego drove in during the last same_road_limit seconds of the current lane run (same road)
-- "During the entire phase": every frame of the island satisfies all of it.
with

road as (
    -- lanes the ego drove in during each lane run: when it entered and when it last was in each
    select
        drive_id,
        ego_id,
        lane_run,
        lane_id,
        min(t_s) as first_s,
        max(t_s) as last_s
    from ego_lanes
    where lane_id is not null
    group by drive_id, ego_id, lane_run, lane_id
),

following as (
    select
        r.drive_id,
        r.ego_id,
        r.actor_id,
        r.frame,
        r.t_s,
        r.actor_kind,
        r.time_headway_s,
        el.lane_run,
        -- the follower is the road user right behind the ego: nobody else in the lane between them
        row_number() over (partition by r.drive_id, r.ego_id, r.frame order by r.lon_gap_m, r.actor_id) as rank_behind
    from relations as r
    inner join ego_lanes as el
        on r.drive_id = el.drive_id and r.ego_id = el.ego_id and r.frame = el.frame
    left join road
        on r.drive_id = road.drive_id and r.ego_id = road.ego_id and el.lane_run = road.lane_run
        and r.actor_lane_id = road.lane_id
        and road.first_s <= r.t_s
        and road.last_s >= r.t_s - $same_road_limit_s
    where el.lane_id is not null
        and r.dx_m < 0
        and r.lon_gap_m > 0
        and (r.same_lane or road.lane_id is not null)
),

islands as (
    select
        *,
        frame - row_number() over (partition by drive_id, ego_id, actor_id, lane_run order by frame) as island
    from following
    where rank_behind = 1
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
having max(t_s) - min(t_s) >= $min_scenario_duration_s
