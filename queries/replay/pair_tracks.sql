-- replay: pair_tracks
-- grain: one row per (drive_id, actor_id, frame) of an ego or actor of a replayed match, inside its window
-- reads: replay_windows, tracks
-- params: none
--
-- The relation query (queries/relations/relations.sql) runs over these rows only, so the replay shows the
-- gap, headway and TTC exactly as matching defines them.
select distinct t.*
from tracks as t
inner join (
    select drive_id, ego_id as actor_id, first_frame, last_frame from replay_windows
    union all
    select drive_id, actor_id, first_frame, last_frame from replay_windows
) as w
    on t.drive_id = w.drive_id
    and t.actor_id = w.actor_id
    and t.frame between w.first_frame and w.last_frame
