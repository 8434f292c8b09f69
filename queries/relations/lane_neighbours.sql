-- relations: lane_neighbours
-- grain: one row per (map_id, lane_id, near_lane_id): a lane driven in the same direction right beside lane_id
-- reads: lanes, lane_line
-- params: none
--
-- Beside means the left or right same-direction neighbour, or a lane that continues it up to two links away
-- (lane_line: its successors and theirs, its predecessors and theirs): where road segments (or a junction's
-- internal lanes) begin at slightly different places, a vehicle beside another can already be on the next
-- segment, or past the junction's internal lane on the one after. Lane changes and adjacency use this one table,
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
    select d.map_id, d.lane_id, l.line_lane_id as near_lane_id, d.side, 1 as hops
    from direct as d
    inner join lane_line as l
        on d.map_id = l.map_id and d.near_lane_id = l.lane_id
    where l.line_lane_id <> l.lane_id
)

select
    map_id,
    lane_id,
    near_lane_id,
    side
from (
    select
        b.*,
        row_number() over (partition by b.map_id, b.lane_id, b.near_lane_id order by b.hops, b.side) as preference
    from beside as b
    left join lane_line as own
        -- where lanes merge, a neighbour's continuation may be the lane's own: that is the same lane, not beside
        on b.map_id = own.map_id and b.lane_id = own.lane_id and b.near_lane_id = own.line_lane_id
    where own.lane_id is null
) as ranked
where preference = 1
