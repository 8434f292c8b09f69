-- coverage: vehicle_at_sample
-- grain: one row per (match_id, sample): the vehicle_actor's values at each sampling event of the match
--        (match/samples.sql); each coverage item keeps the row of the event its `sample` names
-- reads: match_samples, scenario_matches, tracks
-- params: $mph_per_mps (unit constant)
--
--   vehicle_speed_at_start_mph   the vehicle_actor's speed (speed_mps) at the sample's frame
select
    s.match_id,
    s.sample,
    a.speed_mps * $mph_per_mps as vehicle_speed_at_start_mph
from match_samples as s
inner join scenario_matches as m
    on s.match_id = m.match_id
left join tracks as a
    on m.drive_id = a.drive_id and m.actor_id = a.actor_id and s.frame = a.frame
