-- coverage: cut_in_ahead_at_sample (cut_in_ahead_of_ego; logiq_sql's own scenario, not a LogIQ page)
-- grain: one row per (match_id, sample): the cut-in coverage values at each sampling event of the match
--        (match/samples.sql); the scenario samples them at actor_beside_ahead.end, the last frame before the
--        actor is in the Ego's lane
-- reads: match_samples, match_rows (kpis/match_rows.sql)
-- params: $kph_per_mps (unit constant)
--
--   cut_in_side_relative_to_ego   the side of the Ego's lane the actor comes from (left/right: adjacent_side)
--   cut_in_distance_m             bumper-to-bumper gap along the Ego's heading (lon_gap_m)
--   cut_in_speed_kph              the actor's speed
select
    s.match_id,
    s.sample,
    r.adjacent_side as cut_in_side_relative_to_ego,
    r.lon_gap_m as cut_in_distance_m,
    r.actor_speed_mps * $kph_per_mps as cut_in_speed_kph
from match_samples as s
left join match_rows as r
    on s.match_id = r.match_id and s.frame = r.frame
