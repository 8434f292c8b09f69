-- frames: follower_vehicle_frames (the follower scenario's `frames` step, read by phases/follower_vehicle.sql)
-- grain: one row per (drive_id, ego_id, actor_id, frame) at which the actor is behind the ego (dx_m < 0): the
--        measured values and the lane facts of phases/follower_vehicle.sql that no parameter changes
-- reads: relations, ego_road, ego_lanes, drive_inputs, lane_successors (joined on the integer keys drive_key,
--        ego_key, actor_key)
-- params: none
--
-- Split from the phase so that a re-match after a change of same_road_limit or of the headway limits reuses these
-- rows from the step cache and recomputes the phase over the few of them that can hold. Columns (NULL where a lane
-- is unknown, as the phase's conditions read them):
--   follow_gap_m                 greatest(lon_gap_m + lat_gap_m, box_distance_m): an L-shaped path along the ego's
--                                axes (the phase's header says why)
--   follow_headway_s             follow_gap_m / actor_speed_mps (NULL when the actor is not moving forward)
--   past_rear_bumper             lon_gap_m > 0: entirely behind the ego's rear bumper on its heading
--   beside_rear_on_lane_behind   on a lane that continues the ego's (same_lane), not the ego's lane, the boxes apart
--   on_ego_lane                  actor_lane_id = ego_lane_id
--   next_to_first_lane           on a direct predecessor or successor (same_lane) of the first lane of the ego's
--                                lane run
--   past_lane_and_successor      not on the ego's lane nor on a lane the ego's lane directly follows
--   on_leaving_lane              on a direct successor of a lane of the ego's road in this lane run (ego_road)
--   road_first_s, road_last_s    when the ego entered and last was in the actor's lane, if that lane is on the ego's
--                                road in this lane run and the ego entered it by t_s (ego_road); else NULL
--   may_hold                     the row can hold, or be read by the phase, for some value of its parameters: behind
--                                the ego (past_rear_bumper or beside_rear_on_lane_behind) on its road or on a lane
--                                leaving it, or on a lane of its road that the ego has left. A match keeps only these
--                                rows; explain reads them all
with

run_first_lane as (
    -- the lane each lane run began in (its first frame in a lane)
    select drive_key, ego_key, lane_run, lane_id
    from (
        select
            drive_key,
            ego_key,
            lane_run,
            lane_id,
            row_number() over (partition by drive_key, ego_key, lane_run order by frame) as nth
        from ego_lanes
        where lane_id is not null
    ) as numbered
    where nth = 1
),

leaving_lanes as (
    -- each lane leaving the ego's road in a lane run (a direct successor of a lane of it), once: a lane can leave
    -- the road from several of its lanes
    select distinct road.drive_key, road.ego_key, road.lane_run, s.successor_id as lane_id
    from ego_road as road
    inner join drive_inputs as d
        on road.drive_key = d.drive_key
    inner join lane_successors as s
        on d.map_id = s.map_id and road.lane_id = s.lane_id
),

behind as (
    select
        r.drive_key,
        r.ego_key,
        r.actor_key,
        d.map_id,
        r.drive_id,
        r.ego_id,
        r.actor_id,
        r.frame,
        r.t_s,
        r.lane_run,
        r.ego_lane_id,
        r.actor_lane_id,
        r.actor_kind,
        r.lon_gap_m,
        greatest(r.lon_gap_m + r.lat_gap_m, r.box_distance_m) as follow_gap_m,
        case when r.actor_speed_mps > 0
            then greatest(r.lon_gap_m + r.lat_gap_m, r.box_distance_m) / r.actor_speed_mps end
            as follow_headway_s,
        r.lon_gap_m > 0 as past_rear_bumper,
        r.same_lane and r.actor_lane_id <> r.ego_lane_id and r.box_distance_m > 0 as beside_rear_on_lane_behind,
        r.actor_lane_id = r.ego_lane_id as on_ego_lane,
        r.same_lane and fl.lane_id = r.ego_lane_id as next_to_first_lane,
        r.actor_lane_id <> r.ego_lane_id and next_lane.lane_id is null as past_lane_and_successor,
        lv.lane_id is not null as on_leaving_lane,
        road.first_s as road_first_s,
        road.last_s as road_last_s
    from relations as r
    left join run_first_lane as fl
        on r.drive_key = fl.drive_key and r.ego_key = fl.ego_key and r.lane_run = fl.lane_run
    left join ego_road as road
        on r.drive_key = road.drive_key and r.ego_key = road.ego_key and r.lane_run = road.lane_run
        and r.actor_lane_id = road.lane_id
        and road.first_s <= r.t_s
    left join leaving_lanes as lv
        on r.drive_key = lv.drive_key and r.ego_key = lv.ego_key and r.lane_run = lv.lane_run
        and r.actor_lane_id = lv.lane_id
    left join drive_inputs as d
        on r.drive_key = d.drive_key
    left join lane_successors as next_lane
        on d.map_id = next_lane.map_id and r.actor_lane_id = next_lane.lane_id and r.ego_lane_id = next_lane.successor_id
    where r.dx_m < 0
)

select
    *,
    coalesce(
        (past_rear_bumper or beside_rear_on_lane_behind)
            and (on_ego_lane or road_first_s is not null or next_to_first_lane or on_leaving_lane)
        or (road_first_s is not null and past_lane_and_successor),
        false
    ) as may_hold
from behind
