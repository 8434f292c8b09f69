-- kpis: base_object_scenario
-- grain: one row per match: the object's tracking id and kind (kind sampled at the start of the match)
-- reads: scenario_matches, tracks
-- params: none
select
    m.match_id,
    m.actor_id as object_tracking_id,
    a.kind as object_kind
from scenario_matches as m
inner join tracks as a
    on m.drive_id = a.drive_id and m.actor_id = a.actor_id and a.frame = m.start_frame
