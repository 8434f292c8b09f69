-- coverage: ego_at_sample
-- grain: one row per (match_id, sample): the Ego's values at each sampling event of the match (match/samples.sql);
--        each coverage item keeps the row of the event its `sample` names (ego_speed_at_start: start)
-- reads: match_samples, scenario_matches, tracks
-- params: $mph_per_mps (unit constant)
--
--   ego_speed_at_start_mph   the Ego's longitudinal speed (speed_mps) at the sample's frame
select
    s.match_id,
    s.sample,
    e.speed_mps * $mph_per_mps as ego_speed_at_start_mph
from match_samples as s
inner join scenario_matches as m
    on s.match_id = m.match_id
left join tracks as e
    on m.drive_id = e.drive_id and m.ego_id = e.actor_id and s.frame = e.frame
