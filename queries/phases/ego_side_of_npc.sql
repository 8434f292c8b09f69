-- phase: ego_side_of_npc (sut_cut_out, phase 2)
-- grain: one row per (drive_id, ego_id, actor_id, frame) at which the actor is in the ego's lane or a lane beside
--        it: the phase contract (docs/scenarios.md)
-- reads: relations, ego_lanes
-- params: $kinds_csv, $max_gap_s
--
-- Conditions (holds = all of them):
--   actor_kind_ok          the actor is of one of the kinds
--   actor_beside           the actor's lane is beside the ego's lane (adjacent_side, from lane_neighbours: robust
--                          to lane-id changes at segment boundaries)
--   ego_changed_lane_away  the ego's current lane run began with a lane change (ego_lanes.lane_change_side) to
--                          the side away from the actor: "The Ego changes lanes and continues driving in the lane
--                          adjacent to the vehicle_actor"
--   beside_since_change    the actor was beside the ego on this side when that lane change happened (at a frame
--                          at most max_gap after it, so one missed detection does not lose it) and has not been in
--                          the ego's lane since: an actor that moves into the ego's new lane and out again is
--                          cutting in and out itself, not the ego cutting out
-- "The vehicle_actor continues driving in the same lane": had it changed lanes too, it would no longer be beside
-- the ego on that side. segment = the ego's lane run: a second lane change of the ego ends the phase. Chained
-- after ego_on_same_lane, the phase begins on the frame of the lane change (docs/semantics.md).
with

run_changes as (
    -- the side of the lane change that began each lane run (NULL for the first run), and when
    select
        drive_key,
        ego_key,
        lane_run,
        max(lane_change_side) as change_side,
        min(t_s) as change_s
    from ego_lanes
    group by drive_key, ego_key, lane_run
),

near as (
    -- the frames at which the actor is beside the ego or in its lane, with the ego's lane run (one pass over the
    -- relations for the three uses below)
    select
        r.drive_key,
        r.ego_key,
        r.actor_key,
        r.drive_id,
        r.ego_id,
        r.actor_id,
        r.frame,
        r.t_s,
        r.actor_kind,
        r.adjacent_side,
        r.same_lane,
        r.actor_lane_id,
        r.lane_run,
        r.ego_lane_id
    from relations as r
    where r.adjacent_side is not null or r.same_lane
),

first_beside as (
    -- per lane run of the ego, actor and side: the first time the actor is beside the ego on that side
    select
        drive_key,
        ego_key,
        actor_key,
        lane_run,
        adjacent_side,
        min(t_s) as first_s
    from near
    where adjacent_side is not null
    group by drive_key, ego_key, actor_key, lane_run, adjacent_side
),

first_in_lane as (
    -- per lane run of the ego and actor: the first time the actor is in the ego's (new) lane
    select
        drive_key,
        ego_key,
        actor_key,
        lane_run,
        min(t_s) as first_s
    from near
    where same_lane
    group by drive_key, ego_key, actor_key, lane_run
),

conditions as (
    select
        n.drive_id,
        n.ego_id,
        n.actor_id,
        n.frame,
        n.t_s,
        n.lane_run as segment,
        instr($kinds_csv, ',' || n.actor_kind || ',') > 0 as actor_kind_ok,
        n.adjacent_side is not null as actor_beside,
        coalesce(c.change_side <> n.adjacent_side, false) as ego_changed_lane_away,
        coalesce(f.first_s <= c.change_s + $max_gap_s + 1e-6, false)
            and (i.first_s is null or i.first_s > n.t_s) as beside_since_change,
        n.actor_kind,
        n.adjacent_side,
        c.change_side,
        f.first_s - c.change_s as beside_after_change_s,
        n.ego_lane_id,
        n.actor_lane_id,
        n.drive_key,
        n.ego_key,
        n.actor_key
    from near as n
    inner join run_changes as c
        on n.drive_key = c.drive_key and n.ego_key = c.ego_key and n.lane_run = c.lane_run
    left join first_beside as f
        on n.drive_key = f.drive_key and n.ego_key = f.ego_key and n.actor_key = f.actor_key and n.lane_run = f.lane_run
        and n.adjacent_side = f.adjacent_side
    left join first_in_lane as i
        on n.drive_key = i.drive_key and n.ego_key = i.ego_key and n.actor_key = i.actor_key and n.lane_run = i.lane_run
)

select
    *,
    actor_kind_ok and actor_beside and ego_changed_lane_away and beside_since_change as holds
from conditions
