-- relations: lane_neighbours
-- grain: one row per (map_id, lane_id, near_lane_id): a lane driven in the same direction right beside lane_id
-- reads: lanes, lane_successors
-- params: none
--
-- Beside means the left or right same-direction neighbour, or that neighbour's direct successor or
-- predecessor: where road segments (or a junction's internal lanes) begin at slightly different places, a
-- vehicle beside another can already be on the next segment. Lane changes and adjacency use this one table,
-- so a change of lane id at a segment boundary is never mistaken for, or hides, a lane change.
with

direct as (
    select map_id, lane_id, left_lane_id as near_lane_id, 'left' as side
    from lanes
    where left_lane_id is not null and left_same_direction
    union all
    select map_id, lane_id, right_lane_id as near_lane_id, 'right' as side
    from lanes
    where right_lane_id is not null and right_same_direction
),

beside as (
    select map_id, lane_id, near_lane_id, side, 0 as hops
    from direct
    union all
    select d.map_id, d.lane_id, s.successor_id as near_lane_id, d.side, 1 as hops
    from direct as d
    inner join lane_successors as s
        on d.map_id = s.map_id and d.near_lane_id = s.lane_id
    union all
    select d.map_id, d.lane_id, s.lane_id as near_lane_id, d.side, 1 as hops
    from direct as d
    inner join lane_successors as s
        on d.map_id = s.map_id and d.near_lane_id = s.successor_id
)

select
    map_id,
    lane_id,
    near_lane_id,
    side
from (
    select
        *,
        row_number() over (partition by map_id, lane_id, near_lane_id order by hops, side) as preference
    from beside
    where near_lane_id <> lane_id
) as ranked
where preference = 1
