-- junctions: junction_frames
-- grain: one row per (drive_id, actor_id, passage, frame) while the actor is near or in that passage's junction
-- reads: actor_paths, passages
-- params: none
--
-- Joined on the integer keys (drive_key, actor_key), which each row carries beside the ids.
-- Offsets are along the actor's own path (actor_paths.s_m), as the spec defines them: negative behind, positive
-- after, and measured at the box's front (its centre's offset plus half its length): a driver stops with the
-- front at the stop line, and the spec's "distance from an actor to the junction start" is the gap ahead of it.
--   offset_from_junction_start_m  front s - entry s: < 0 before the front reaches the junction, >= 0 after;
--                                 NULL when the entry was not observed (the track starts inside)
--   offset_from_junction_end_m    front s - exit s: <= 0 until the front leaves, > 0 after; NULL when the exit
--                                 was not observed (the track ends inside)
--   in_junction                   the frame lies within the passage (entry frame to exit frame)
-- Frames are kept from 30 m of path before the entry to 30 m after the exit (longer than every offset
-- parameter's default); an actor between two junctions has a row for each.
select
    p.drive_id,
    p.actor_id,
    j.passage,
    j.junction_id,
    p.frame,
    p.t_s,
    p.s_m,
    case when j.entry_observed then p.s_m + p.length_m / 2 - j.entry_s_m end as offset_from_junction_start_m,
    case when j.exit_observed then p.s_m + p.length_m / 2 - j.exit_s_m end as offset_from_junction_end_m,
    p.frame between j.entry_frame and j.exit_frame as in_junction,
    p.drive_key,
    p.actor_key
from actor_paths as p
inner join passages as j
    on p.drive_key = j.drive_key and p.actor_key = j.actor_key
    and p.s_m between j.entry_s_m - 30.0 and j.exit_s_m + 30.0
