-- match: samples
-- grain: one row per (match_id, sample): the frame at which each sampling event of a match happens, for the
--        coverage items' `sample` (docs/scenarios.md)
-- reads: scenario_matches
-- params: $phase_1_name .. $phase_4_name (NULL past the scenario's last phase)
--
--   start, end                      the first and the last frame of the match
--   <phase>.start, <phase>.end      the first and the last frame of that phase in the match
select match_id, 'start' as sample, start_frame as frame from scenario_matches
union all
select match_id, 'end' as sample, end_frame as frame from scenario_matches
union all
select match_id, $phase_1_name || '.start' as sample, p1_start_frame as frame from scenario_matches
where p1_start_frame is not null
union all
select match_id, $phase_1_name || '.end' as sample, p1_end_frame as frame from scenario_matches
where p1_end_frame is not null
union all
select match_id, $phase_2_name || '.start' as sample, p2_start_frame as frame from scenario_matches
where p2_start_frame is not null
union all
select match_id, $phase_2_name || '.end' as sample, p2_end_frame as frame from scenario_matches
where p2_end_frame is not null
union all
select match_id, $phase_3_name || '.start' as sample, p3_start_frame as frame from scenario_matches
where p3_start_frame is not null
union all
select match_id, $phase_3_name || '.end' as sample, p3_end_frame as frame from scenario_matches
where p3_end_frame is not null
union all
select match_id, $phase_4_name || '.start' as sample, p4_start_frame as frame from scenario_matches
where p4_start_frame is not null
union all
select match_id, $phase_4_name || '.end' as sample, p4_end_frame as frame from scenario_matches
where p4_end_frame is not null
