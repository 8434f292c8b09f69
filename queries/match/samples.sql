-- match: samples
-- grain: one row per (match_id, sample): the frame at which each sampling event of a match happens, for the
--        coverage items' `sample` (docs/scenarios.md)
-- reads: scenario_matches, scenario_match_phases (match/match_phases.sql)
-- params: none
--
--   start, end                      the first and the last frame of the match
--   <phase>.start, <phase>.end      the first and the last frame of that phase in the match
select match_id, 'start' as sample, start_frame as frame from scenario_matches
union all
select match_id, 'end' as sample, end_frame as frame from scenario_matches
union all
select match_id, phase || '.start' as sample, start_frame as frame from scenario_match_phases
union all
select match_id, phase || '.end' as sample, end_frame as frame from scenario_match_phases
