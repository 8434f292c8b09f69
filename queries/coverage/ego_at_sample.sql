-- coverage: ego_at_sample
-- grain: one row per (match_id, sample): the Ego's values at each sampling event of the match (match/samples.sql);
--        each coverage item keeps the row of the event its `sample` names (ego_speed_at_start: start)
-- reads: match_samples, match_rows (kpis/match_rows.sql)
-- params: $mph_per_mps (unit constant)
--
--   ego_speed_at_start_mph   the Ego's longitudinal speed (speed_mps) at the sample's frame
select
    s.match_id,
    s.sample,
    r.ego_speed_mps * $mph_per_mps as ego_speed_at_start_mph
from match_samples as s
left join match_rows as r
    on s.match_id = r.match_id and s.frame = r.frame
