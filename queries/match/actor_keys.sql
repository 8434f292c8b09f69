-- match: actor_keys
-- grain: one row per (drive_id, actor_id) of the batch's drives: the actor's integer keys (tracks.drive_key,
--        actor_key), by which match/phase_frames.sql keys a phase's rows (ego and actor alike) so that the match
--        steps after it join, window and group on integers
-- reads: tracks, run_drives
-- params: none
select distinct
    drive_id,
    actor_id,
    drive_key,
    actor_key
from tracks
where drive_id in (select drive_id from run_drives)
