-- relations: ego_road
-- grain: one row per (drive_id, ego_id, lane_run, lane_id) of a lane the ego drove in during that lane run: when
--        it entered the lane and when it was last in it
-- reads: ego_lanes
-- params: none
--
-- The ego's road in a lane run: the line of lanes it drove since its last lane change (ego_lanes.lane_id), one lane
-- after another through segment boundaries and junctions. The follower scenario reads it ("the same road").
--   first_s   t_s of the ego's first frame in the lane during the lane run
--   last_s    t_s of its last frame in the lane during the lane run
select
    drive_key,
    ego_key,
    lane_run,
    lane_id,
    min(drive_id) as drive_id,
    min(ego_id) as ego_id,
    min(t_s) as first_s,
    max(t_s) as last_s
from ego_lanes
where lane_id is not null
group by drive_key, ego_key, lane_run, lane_id
