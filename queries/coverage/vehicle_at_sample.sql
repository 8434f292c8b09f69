-- coverage: vehicle_at_sample
-- grain: one row per (match_id, sample): the vehicle_actor's values at each sampling event of the match
--        (match/samples.sql); each coverage item keeps the row of the event its `sample` names
-- reads: match_samples, match_rows (kpis/match_rows.sql)
-- params: $mph_per_mps (unit constant)
--
--   vehicle_speed_at_start_mph   the vehicle_actor's speed (speed_mps) at the sample's frame
select
    s.match_id,
    s.sample,
    r.actor_speed_mps * $mph_per_mps as vehicle_speed_at_start_mph
from match_samples as s
left join match_rows as r
    on s.match_id = r.match_id and s.frame = r.frame
