-- match: scenario_phases
-- grain: one row per phase of the scenario: its name and the duration limits it must meet in a match, for
--        match/sequential.sql and match/match_phases.sql
-- reads: none
-- params: $phase_1_name, $phase_1_min_duration_s, $phase_1_max_duration_s (the select below is written for
--         phase 1; a match runs it for each phase k of the scenario with $phase_k_..., joined by union all:
--         `logiq-sql render` prints it)
--
--   phase_index   1 for the first phase
--   phase         the phase's name in the scenario file
--   min_s, max_s  the values of the durations the phase names (min_duration: 0 when it names none; max_duration:
--                 NULL when it names none)
select
    1 as phase_index,
    $phase_1_name as phase,
    cast($phase_1_min_duration_s as double) as min_s,
    cast($phase_1_max_duration_s as double) as max_s
