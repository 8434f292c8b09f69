-- kpis: base_lane_following_scenario
-- grain: one row per match: the least bumper-to-bumper gap (lon_gap_m) between Ego and vehicle over the match
-- reads: match_rows
-- params: none
select
    match_id,
    min(lon_gap_m) as ego_min_distance_to_vehicle_m
from match_rows
where related
group by match_id
