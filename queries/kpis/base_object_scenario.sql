-- kpis: base_object_scenario
-- grain: one row per match: the object's tracking id
-- reads: scenario_matches
-- params: none
select
    m.match_id,
    m.actor_id as object_tracking_id
from scenario_matches as m
