-- phase: ego_on_same_lane (sut_cut_out, phase 1)
-- grain: one row per (drive_id, ego_id, actor_id, frame) at which the actor is ahead of the ego (dx_m > 0): the
--        phase contract (docs/scenarios.md)
-- reads: relations, ego_lanes, drive_inputs, lane_successors (joined on the integer keys drive_key, ego_key)
-- params: $kinds_csv, $min_distance_from_sut_in_time_units_s, $max_distance_from_sut_in_time_units_s
--
-- Conditions (holds = all of them):
--   actor_kind_ok        the actor is of one of the kinds
--   actor_ahead          entirely ahead of the ego's front bumper (dx > 0 and lon_gap > 0)
--   actor_in_ego_lane    the actor's lane is the ego's lane or one that continues it (same_lane). The ego's
--                        lane is the lane its centre is in (ego_lanes); a lane change is dated at the crossing,
--                        so the lane and the lane run switch on the same frame. Not the
--                        lane after a left or right turn's lane unless the ego drives it in this lane run: a
--                        car that has turned off is no longer ahead in the lane of an ego going on (tracks are
--                        recorded, so the ego's own path is known); on the turn's lane it is still partly ahead
--   actor_nearest        it is the nearest road user (any kind) ahead of the ego in that lane: the one the ego
--                        follows. One off to the side of the ego (lat_gap_m > 0) and heading more than 30 degrees
--                        off the ego's heading (round a bend) is not when a road user straight in front of the ego
--                        (lat_gap_m = 0), in its lane or the lane beside, is nearer: in a double left turn the car
--                        right in front of the ego may be labelled the next lane while one 10-15 m to the side,
--                        further round the bend, is labelled the ego's
--   headway_in_range     time headway (gap / ego speed) in [min_distance_from_sut_in_time_units,
--                        max_distance_from_sut_in_time_units]
-- segment = the ego's lane run, so the phase ends at the latest on the frame before the ego's lane change.
with

turned_onto as (
    -- the lanes a left or right turn leads onto from a lane, past the turn (a car still on the turn's own lane,
    -- inside the junction, is partly in front of the ego yet); distinct: two turns onto one lane give one row
    select distinct s.map_id, s.lane_id, n.successor_id as turn_lane_id
    from lane_successors as s
    inner join lane_successors as n
        on s.map_id = n.map_id and s.successor_id = n.lane_id
    where s.turn in ('left', 'right', 'u_turn')
),

run_lanes as (
    -- the lanes the ego drives in each lane run
    select distinct drive_key, ego_key, lane_run, lane_id
    from ego_lanes
    where lane_id is not null
),

ahead as (
    select
        r.drive_key,
        r.ego_key,
        r.actor_key,
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
        r.lat_gap_m,
        r.rel_heading_rad,
        r.time_headway_s,
        r.lon_gap_m > 0 as actor_ahead,
        r.same_lane and (turn.turn_lane_id is null or driven.lane_id is not null) as actor_in_ego_lane,
        -- straight in front of the ego (the boxes overlap across its heading) in its lane or the one beside:
        -- whatever the lane labels say, the ego follows it, so it stands between the ego and those further on
        r.lat_gap_m = 0 and (r.same_lane or r.adjacent_side is not null) as actor_in_line
    from relations as r
    inner join drive_inputs as d
        on r.drive_key = d.drive_key
    left join turned_onto as turn
        on d.map_id = turn.map_id and r.ego_lane_id = turn.lane_id and r.actor_lane_id = turn.turn_lane_id
    left join run_lanes as driven
        on r.drive_key = driven.drive_key and r.ego_key = driven.ego_key and r.lane_run = driven.lane_run
        and r.actor_lane_id = driven.lane_id
    where r.dx_m > 0
),

nearest_gap as (
    -- the road user the ego follows is the one right ahead of it in the lane: the least gap per frame (grouped
    -- minima rather than a ranking window: a hash aggregate over the few rows in lane, not a sort of them all)
    select drive_key, ego_key, frame, min(lon_gap_m) as lon_gap_m
    from ahead
    where actor_ahead and actor_in_ego_lane
    group by drive_key, ego_key, frame
),

nearest as (
    -- of several at that least gap, the smallest actor_id
    select a.drive_key, a.ego_key, a.frame, min(a.actor_key) as actor_key
    from ahead as a
    inner join nearest_gap as g
        on a.drive_key = g.drive_key and a.ego_key = g.ego_key and a.frame = g.frame and a.lon_gap_m = g.lon_gap_m
    where a.actor_ahead and a.actor_in_ego_lane
    group by a.drive_key, a.ego_key, a.frame
),

in_line_gap as (
    -- the nearest road user straight in front of the ego, in its lane or the one beside
    select drive_key, ego_key, frame, min(lon_gap_m) as lon_gap_m
    from ahead
    where actor_ahead and actor_in_line
    group by drive_key, ego_key, frame
),

ranked as (
    select
        a.*,
        n.actor_key is not null
            -- one off to the side of the ego and turned by a bend (more than 30 degrees: an ego changing lanes
            -- turns by far less) is behind whoever is nearer and straight in front of the ego
            and (a.lat_gap_m = 0 or abs(a.rel_heading_rad) <= pi() / 6 or l.lon_gap_m is null
                or l.lon_gap_m >= a.lon_gap_m) as is_nearest
    from ahead as a
    left join nearest as n
        on a.drive_key = n.drive_key and a.ego_key = n.ego_key and a.frame = n.frame and a.actor_key = n.actor_key
    left join in_line_gap as l
        on a.drive_key = l.drive_key and a.ego_key = l.ego_key and a.frame = l.frame
),

conditions as (
    select
        drive_id,
        ego_id,
        actor_id,
        frame,
        t_s,
        lane_run as segment,
        instr($kinds_csv, ',' || actor_kind || ',') > 0 as actor_kind_ok,
        actor_ahead,
        actor_in_ego_lane,
        actor_ahead and actor_in_ego_lane and is_nearest as actor_nearest,
        coalesce(time_headway_s >= $min_distance_from_sut_in_time_units_s
            and time_headway_s <= $max_distance_from_sut_in_time_units_s, false) as headway_in_range,
        actor_kind,
        ego_lane_id,
        actor_lane_id,
        lon_gap_m,
        time_headway_s,
        drive_key,
        ego_key,
        actor_key
    from ranked
)

select
    *,
    actor_kind_ok and actor_ahead and actor_in_ego_lane and actor_nearest and headway_in_range as holds
from conditions
