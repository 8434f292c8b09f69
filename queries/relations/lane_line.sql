-- relations: lane_line
-- grain: one row per (map_id, lane_id, line_lane_id): a lane and the lanes that continue it in the lane graph, up
--        to two links away in one direction (successors and their successors, predecessors and theirs), and itself
-- reads: lanes, lane_successors
-- params: none
--
-- "The same lane" across a road-segment boundary: relations.same_lane and the ego's lane changes both use it. Two
-- links, because a junction's internal lane often sits between two road segments (SUMO: edge -> internal lane
-- -> edge), so a car on the next edge is still in the lane of one on the previous one. Never a successor's other
-- predecessor: two lanes that merge into one are not one lane.
with

ahead as (
    select map_id, lane_id, successor_id as line_lane_id from lane_successors
    union
    select a.map_id, a.lane_id, b.successor_id as line_lane_id
    from lane_successors as a
    inner join lane_successors as b
        on a.map_id = b.map_id and a.successor_id = b.lane_id
)

select map_id, lane_id, lane_id as line_lane_id from lanes
union
select map_id, lane_id, line_lane_id from ahead
union
select map_id, line_lane_id as lane_id, lane_id as line_lane_id from ahead
