-- relations: actor_lanes
-- grain: one row per (drive_key, actor_key, frame) of the run's drives that lies in a lane: its best lane (the
--        integer keys of the row's drive and actor; tracks has their ids)
-- reads: track_lanes (every lane within 3 m of each track row, from the look-up at ingest), run_drives
-- params: $lane_calculation_tolerance_length_m
--
-- An actor is in a lane when its centre is within lane_calculation_tolerance_length of the lane polygon
-- and its heading is within 90 degrees of the lane direction. Of several such lanes the best is the
-- nearest (0 when inside), then the one best aligned with the heading, then the smallest id.
--
-- Ingest marks that lane on each row (track_lanes.best_lane: the same order over the lanes within 90 degrees),
-- so no row's lanes are ranked here: the best of the lanes within the tolerance is the best lane when it is
-- within the tolerance (it is the nearest), and there is none when it is not.
select
    drive_key,
    actor_key,
    frame,
    lane_id,
    dist_m as lane_dist_m
from track_lanes
where drive_id in (select drive_id from run_drives)
    and best_lane
    and dist_m <= $lane_calculation_tolerance_length_m
