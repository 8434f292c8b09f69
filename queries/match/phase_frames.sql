-- match: phase_frames
-- grain: one row per (phase_index, drive_key, ego_key, actor_key, segment, frame) at which a phase of the
--        scenario holds: the phases as rows, keyed by integers, for match/phase_runs.sql
-- reads: phase_1 (the select below is written for phase 1; a match runs it for each phase k of the scenario,
--        reading phase_k with phase_index k, joined by union all: `logiq-sql render` prints it)
-- params: none
--
-- Every phase query returns the pair's integer keys beside its ids (the phase contract); the steps after this one
-- read only the keys.
select distinct
    1 as phase_index,
    p.drive_key,
    p.ego_key,
    p.actor_key,
    p.segment,
    p.frame,
    p.t_s
from phase_1 as p
where p.holds
