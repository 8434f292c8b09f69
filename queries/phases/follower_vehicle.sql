-- phase: follower_vehicle
-- grain: one row per (drive_id, ego_id, actor_id, frame) at which the actor is behind the ego (dx_m < 0): the
--        phase contract (docs/scenarios.md): keys, frame, t_s, segment, holds, each condition and the values
--        it tests
-- reads: scenario_frames (phases/follower_vehicle_frames.sql: the measured values and the lane facts no parameter
--        changes), ego_road, relations, drive_inputs, lane_successors (joined on the integer keys drive_key,
--        ego_key, actor_key)
-- params: $kinds_csv, $min_distance_from_sut_in_time_units_s, $max_distance_from_sut_in_time_units_s,
--         $same_road_limit_s
--
-- Conditions (holds = all of them):
--   ego_in_lane          the ego is in a lane (ego_lanes.lane_id)
--   actor_kind_ok        the actor is of one of the kinds
--   actor_behind         entirely behind the ego's rear bumper (dx < 0 and lon_gap > 0: an actor alongside, or
--                        overlapping the ego, is not following it), or behind it along the road: dx < 0, on a lane
--                        that continues the ego's (same_lane) and that the ego drove before its present one in this
--                        lane run, within same_road_limit, the boxes apart. Through a sharp turn the rear of a long
--                        ego swings across the lane it came from, and the car following it round the corner is off
--                        to the side of its rear on its new heading
--   actor_on_ego_road    the actor's lane is the ego's lane, or a lane the ego drove in during the last
--                        same_road_limit seconds of its lane run, or (while the ego is still in the first lane of
--                        its lane run, so where it came from is unknown) its direct predecessor/successor
--                        (same_lane). Once the ego has left a lane, a predecessor it did not drive is another
--                        road: behind a junction every approach is a predecessor of the exit lane
--   actor_path_follows_ego  on a lane of the ego's road that the ego has left, and its direct successor too
--                        (the ego is past the fork of a junction), the actor is not bound elsewhere: it does not,
--                        within same_road_limit of leaving that lane, drive on into a successor of it without ever
--                        entering a lane the ego entered after it. An actor bound for another exit no longer follows
--                        the ego once the ego is through the fork (it still stands between the ego and those behind
--                        it); one that leaves the lane by a lane change, or is not seen leaving it, still does
--   actor_nearest        it is the nearest road user (any kind) behind the ego on its road, by follow_gap_m:
--                        the one that follows the ego; a car behind it follows it, not the ego. A road user
--                        turning off the ego's road (on a direct successor of a lane of the road, itself not on
--                        it) still counts as between: the car behind a right-turner follows the right-turner
--   headway_in_range     follow_headway_s (follow_gap_m / actor speed) in [min_distance_from_sut_in_time_units,
--                        max_distance_from_sut_in_time_units]
-- follow_gap_m = greatest(lon_gap_m + lat_gap_m, box_distance_m): an L-shaped path along the ego's axes (lon_gap
-- alone for two cars in line). After the ego turns at a junction, the projection on its new heading alone shrinks
-- a 100 m gap along the road to a few metres; the road runs from the approach round the corner.
-- segment = the ego's lane run: "The Ego drives in one lane", so a run never spans a lane change of the ego.
with

leaving as (
    -- lanes that turn off the ego's road: the direct successors of the lanes it drove in each lane run
    select road.drive_key, road.ego_key, road.lane_run, s.successor_id as lane_id, road.first_s, road.last_s
    from ego_road as road
    inner join drive_inputs as d
        on road.drive_key = d.drive_key
    inner join lane_successors as s
        on d.map_id = s.map_id and road.lane_id = s.lane_id
),

on_road as (
    -- the actor's lane is a lane the ego drove in during the last same_road_limit seconds of its lane run
    select *, coalesce(road_last_s >= t_s - $same_road_limit_s, false) as on_road_lane
    from scenario_frames
),

behind as (
    select
        drive_key,
        ego_key,
        actor_key,
        map_id,
        drive_id,
        ego_id,
        actor_id,
        frame,
        t_s,
        lane_run,
        ego_lane_id,
        actor_lane_id,
        actor_kind,
        lon_gap_m,
        follow_gap_m,
        follow_headway_s,
        -- behind along the road: past the ego's rear bumper on its heading, or on a lane the ego drove before its
        -- present one in the same line of lanes (a long ego turning sharply swings its rear across the lane behind
        -- it, so a car following it round the corner is beside its rear on its new heading for a second or two),
        -- boxes apart. Never a lane beside: a car alongside in a lane the ego drifted through is not behind it
        past_rear_bumper or (beside_rear_on_lane_behind and on_road_lane) as actor_behind,
        coalesce(on_ego_lane or on_road_lane or next_to_first_lane, false) as actor_on_ego_road,
        -- when the ego entered the lane of its road the actor is on, if it has left that lane and its successor
        -- since (it is past a fork)
        case when on_road_lane and past_lane_and_successor then road_first_s end as left_lane_first_s,
        on_leaving_lane
    from on_road
),

left_lanes as (
    -- actors behind the ego on a lane of its road that the ego has left: the lane, and when the actor was last on it
    select drive_key, ego_key, actor_key, map_id, actor_lane_id, left_lane_first_s, max(t_s) as last_on_lane_s
    from behind
    where left_lane_first_s is not null
    group by drive_key, ego_key, actor_key, map_id, actor_lane_id, left_lane_first_s
),

diverging as (
    -- of those, the actors that, within same_road_limit of leaving that lane, drive on into one of its successors
    -- but never into a lane the ego entered after it: bound for another exit (the pair's own relation rows: the actor
    -- is near the ego meanwhile). An actor that leaves by a lane change is not bound elsewhere by this rule
    select l.drive_key, l.ego_key, l.actor_key, l.actor_lane_id
    from left_lanes as l
    inner join relations as r
        on l.drive_key = r.drive_key and l.ego_key = r.ego_key and l.actor_key = r.actor_key
        and r.t_s > l.last_on_lane_s and r.t_s <= l.last_on_lane_s + $same_road_limit_s
        and r.actor_lane_id <> l.actor_lane_id
    left join lane_successors as onward
        on l.map_id = onward.map_id and l.actor_lane_id = onward.lane_id and r.actor_lane_id = onward.successor_id
    left join (select distinct drive_key, ego_key, lane_id, first_s from ego_road) as later
        on r.drive_key = later.drive_key and r.ego_key = later.ego_key and r.actor_lane_id = later.lane_id
        and later.first_s > l.left_lane_first_s
    group by l.drive_key, l.ego_key, l.actor_key, l.actor_lane_id
    having max(case when onward.lane_id is not null then 1 else 0 end) = 1
        and max(case when later.lane_id is not null then 1 else 0 end) = 0
),

turning_off as (
    -- road users behind the ego on a lane leaving its road (within same_road_limit, as for the road itself)
    select b.drive_key, b.ego_key, b.frame, min(b.follow_gap_m) as follow_gap_m
    from behind as b
    inner join leaving as lv
        on b.drive_key = lv.drive_key and b.ego_key = lv.ego_key and b.lane_run = lv.lane_run
        and b.actor_lane_id = lv.lane_id
        and lv.first_s <= b.t_s
        and lv.last_s >= b.t_s - $same_road_limit_s
    where b.actor_behind and not b.actor_on_ego_road and b.on_leaving_lane
    group by b.drive_key, b.ego_key, b.frame
),

nearest_gap as (
    -- the follower is the road user right behind the ego on its road, nobody else between them: the least gap
    -- per frame (grouped minima rather than a ranking window: a hash aggregate over the few rows on the road,
    -- not a sort of them all), a road user turning off the road counted as between
    select drive_key, ego_key, frame, min(follow_gap_m) as follow_gap_m
    from (
        select drive_key, ego_key, frame, follow_gap_m
        from behind
        where actor_behind and actor_on_ego_road
        union all
        select drive_key, ego_key, frame, follow_gap_m
        from turning_off
    ) as between_ego_and_follower
    group by drive_key, ego_key, frame
),

nearest as (
    -- of several at that least gap, the smallest actor_id
    select b.drive_key, b.ego_key, b.frame, min(b.actor_key) as actor_key
    from behind as b
    inner join nearest_gap as g
        on b.drive_key = g.drive_key and b.ego_key = g.ego_key and b.frame = g.frame and b.follow_gap_m = g.follow_gap_m
    where b.actor_behind and b.actor_on_ego_road
    group by b.drive_key, b.ego_key, b.frame
),

ranked as (
    select
        b.*,
        n.actor_key is not null as is_nearest,
        dv.actor_key is null as actor_path_follows_ego
    from behind as b
    left join nearest as n
        on b.drive_key = n.drive_key and b.ego_key = n.ego_key and b.frame = n.frame and b.actor_key = n.actor_key
    left join diverging as dv
        on b.drive_key = dv.drive_key and b.ego_key = dv.ego_key and b.actor_key = dv.actor_key
        and b.actor_lane_id = dv.actor_lane_id and b.left_lane_first_s is not null
),

conditions as (
    select
        drive_id,
        ego_id,
        actor_id,
        frame,
        t_s,
        lane_run as segment,
        ego_lane_id is not null as ego_in_lane,
        instr($kinds_csv, ',' || actor_kind || ',') > 0 as actor_kind_ok,
        actor_behind,
        actor_on_ego_road,
        actor_path_follows_ego,
        actor_behind and actor_on_ego_road and is_nearest as actor_nearest,
        coalesce(follow_headway_s >= $min_distance_from_sut_in_time_units_s
            and follow_headway_s <= $max_distance_from_sut_in_time_units_s, false) as headway_in_range,
        actor_kind,
        ego_lane_id,
        actor_lane_id,
        lon_gap_m,
        follow_gap_m,
        follow_headway_s,
        drive_key,
        ego_key,
        actor_key
    from ranked
)

select
    *,
    ego_in_lane and actor_kind_ok and actor_behind and actor_on_ego_road and actor_path_follows_ego
        and actor_nearest and headway_in_range as holds
from conditions
