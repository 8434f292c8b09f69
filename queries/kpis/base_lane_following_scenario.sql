-- kpis: base_lane_following_scenario
-- grain: one row per match: the least bumper-to-bumper gap (lon_gap_m) between Ego and vehicle over the match
-- reads: scenario_matches, relations
-- params: none
select
    m.match_id,
    min(r.lon_gap_m) as ego_min_distance_to_vehicle_m
from scenario_matches as m
inner join relations as r
    on m.drive_id = r.drive_id and m.ego_id = r.ego_id and m.actor_id = r.actor_id
    and r.frame between m.start_frame and m.end_frame
group by m.match_id
