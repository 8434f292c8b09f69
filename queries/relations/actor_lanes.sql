-- relations: actor_lanes
-- grain: one row per (drive_id, actor_id, frame) of the run's drives that lies in a lane: its best lane, with
--        the row's integer keys (drive_key, actor_key)
-- reads: track_lanes (every lane within 3 m of each track row, from shapely at ingest), run_drives
-- params: $lane_calculation_tolerance_length_m
--
-- An actor is in a lane when its centre is within lane_calculation_tolerance_length of the lane polygon
-- and its heading is within 90 degrees of the lane direction. Of several such lanes the best is the
-- nearest (0 when inside), then the one best aligned with the heading, then the smallest id.
select
    drive_key,
    actor_key,
    drive_id,
    actor_id,
    frame,
    lane_id,
    dist_m as lane_dist_m
from (
    select
        *,
        row_number() over (
            partition by drive_key, row_key
            order by dist_m, abs(heading_diff_rad), lane_id
        ) as rank_in_frame
    from track_lanes
    where drive_id in (select drive_id from run_drives)
        and dist_m <= $lane_calculation_tolerance_length_m
        and abs(heading_diff_rad) < pi() / 2
) as ranked
where rank_in_frame = 1
