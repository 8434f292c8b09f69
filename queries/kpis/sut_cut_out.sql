-- kpis: sut_cut_out
-- grain: one row per match: the coverage samples taken at the Ego's lane change (the first frame of phase 2,
--        ego_side_of_npc), spec units
-- reads: scenario_matches, relations, tracks
-- params: $kph_per_mps (unit constant)
--
--   speed_at_change_lane_kph        the vehicle_actor's speed
--   distance_at_change_lane_m       bumper-to-bumper gap along the Ego's heading (lon_gap_m, the distance the
--                                   headway and ego_min_distance_to_vehicle use)
--   side_of_npc_relative_to_ego_at_lane_change
--                                   the side of the Ego's new lane on which the actor's lane lies (left/right)
select
    m.match_id,
    a.speed_mps * $kph_per_mps as speed_at_change_lane_kph,
    r.lon_gap_m as distance_at_change_lane_m,
    r.adjacent_side as side_of_npc_relative_to_ego_at_lane_change
from scenario_matches as m
inner join relations as r
    on m.drive_id = r.drive_id and m.ego_id = r.ego_id and m.actor_id = r.actor_id and m.p2_start_frame = r.frame
inner join tracks as a
    on m.drive_id = a.drive_id and m.actor_id = a.actor_id and m.p2_start_frame = a.frame
