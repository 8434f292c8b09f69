-- match: phase_frames
-- grain: one row per (phase_index, drive_id, ego_id, actor_id, segment, frame) at which a phase of the scenario
--        holds: the phases as rows, for match/phase_runs.sql
-- reads: phase_1 (the select below is written for phase 1; a match runs it for each phase k of the scenario,
--        reading phase_k with phase_index k, joined by union all: `logiq-sql render` prints it)
-- params: none
select distinct
    1 as phase_index,
    drive_id,
    ego_id,
    actor_id,
    segment,
    frame,
    t_s
from phase_1
where holds
