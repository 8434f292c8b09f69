-- match: phase_frames
-- grain: one row per (phase_index, drive_key, ego_key, actor_key, segment, frame) at which a phase of the
--        scenario holds: the phases as rows, keyed by integers, for match/phase_runs.sql
-- reads: phase_1 (the select below is written for phase 1; a match runs it for each phase k of the scenario,
--        reading phase_k with phase_index k, joined by union all: `logiq-sql render` prints it), actor_keys
-- params: none
--
-- A phase query returns the string ids (the phase contract); the ego's and the actor's integer keys come from
-- actor_keys here, once per holding row, and the steps after this one read only the keys.
select distinct
    1 as phase_index,
    e.drive_key,
    e.actor_key as ego_key,
    a.actor_key,
    p.segment,
    p.frame,
    p.t_s
from phase_1 as p
inner join actor_keys as e
    on p.drive_id = e.drive_id and p.ego_id = e.actor_id
inner join actor_keys as a
    on p.drive_id = a.drive_id and p.actor_id = a.actor_id
where p.holds
