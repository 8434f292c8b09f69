-- match: match_phases
-- grain: one row per (match_id, phase_index): the interval of each phase of each match (the match_phases table)
-- reads: scenario_matches, scenario_match, scenario_phases
-- params: none
select
    m.match_id,
    m.scenario,
    cast(p.phase_index as bigint) as phase_index,
    n.phase,
    p.phase_start_frame as start_frame,
    p.phase_end_frame as end_frame,
    p.phase_start_s as start_s,
    p.phase_end_s as end_s
from scenario_matches as m
inner join scenario_match as p
    on m.drive_key = p.drive_key and m.ego_key = p.ego_key and m.actor_key = p.actor_key
    and m.start_frame = p.start_frame
inner join scenario_phases as n
    on p.phase_index = n.phase_index
