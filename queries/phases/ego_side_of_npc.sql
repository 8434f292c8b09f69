-- phase: ego_side_of_npc (sut_cut_out, phase 2)
-- grain: one row per (drive_id, ego_id, actor_id, frame) at which the actor is in the ego's lane or a lane beside
--        it: the phase contract (docs/scenarios.md)
-- reads: relations, ego_lanes
-- params: $kinds_csv
--
-- Conditions (holds = all of them):
--   actor_kind_ok          the actor is of one of the kinds
--   actor_beside           the actor's lane is beside the ego's lane (adjacent_side, from lane_neighbours: robust
--                          to lane-id changes at segment boundaries)
--   ego_changed_lane_away  the ego's current lane run began with a lane change (ego_lanes.lane_change_side) to
--                          the side away from the actor: "The Ego changes lanes and continues driving in the lane
--                          adjacent to the vehicle_actor"
-- "The vehicle_actor continues driving in the same lane": had it changed lanes too, it would no longer be beside
-- the ego on that side. segment = the ego's lane run: a second lane change of the ego ends the phase. Chained
-- after ego_on_same_lane, the phase begins on the frame of the lane change (docs/semantics.md).
with

run_changes as (
    -- the side of the lane change that began each lane run (NULL for the first run)
    select
        drive_id,
        ego_id,
        lane_run,
        max(lane_change_side) as change_side
    from ego_lanes
    group by drive_id, ego_id, lane_run
),

conditions as (
    select
        r.drive_id,
        r.ego_id,
        r.actor_id,
        r.frame,
        r.t_s,
        el.lane_run as segment,
        instr($kinds_csv, ',' || r.actor_kind || ',') > 0 as actor_kind_ok,
        r.adjacent_side is not null as actor_beside,
        coalesce(c.change_side <> r.adjacent_side, false) as ego_changed_lane_away,
        r.actor_kind,
        r.adjacent_side,
        c.change_side,
        el.lane_id as ego_lane_id,
        r.actor_lane_id
    from relations as r
    inner join ego_lanes as el
        on r.drive_id = el.drive_id and r.ego_id = el.ego_id and r.frame = el.frame
    inner join run_changes as c
        on el.drive_id = c.drive_id and el.ego_id = c.ego_id and el.lane_run = c.lane_run
    where r.adjacent_side is not null or r.same_lane
)

select
    *,
    actor_kind_ok and actor_beside and ego_changed_lane_away as holds
from conditions
