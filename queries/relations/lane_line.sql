-- relations: lane_line
-- grain: one row per (map_id, lane_id, line_lane_id): a lane and the lanes that continue it in the lane graph,
--        its direct successors and predecessors (and itself)
-- reads: lanes, lane_successors
-- params: none
--
-- "The same lane" across a road-segment boundary: relations.same_lane and the ego's lane changes both use it.
select map_id, lane_id, lane_id as line_lane_id from lanes
union
select map_id, lane_id, successor_id as line_lane_id from lane_successors
union
select map_id, successor_id as lane_id, lane_id as line_lane_id from lane_successors
