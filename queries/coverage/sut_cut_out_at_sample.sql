-- coverage: sut_cut_out_at_sample
-- grain: one row per (match_id, sample): the lane-change coverage values at each sampling event of the match
--        (match/samples.sql); sut_cut_out samples them at ego_side_of_npc.start, the frame of the Ego's lane change
-- reads: match_samples, match_rows (kpis/match_rows.sql)
-- params: $kph_per_mps (unit constant)
--
--   speed_at_change_lane_kph        the vehicle_actor's speed
--   distance_at_change_lane_m       bumper-to-bumper gap along the Ego's heading (lon_gap_m, the distance the
--                                   headway and ego_min_distance_to_vehicle use)
--   side_of_npc_relative_to_ego_at_lane_change
--                                   the side of the Ego's new lane on which the actor's lane lies (left/right)
select
    s.match_id,
    s.sample,
    r.actor_speed_mps * $kph_per_mps as speed_at_change_lane_kph,
    r.lon_gap_m as distance_at_change_lane_m,
    r.adjacent_side as side_of_npc_relative_to_ego_at_lane_change
from match_samples as s
left join match_rows as r
    on s.match_id = r.match_id and s.frame = r.frame
