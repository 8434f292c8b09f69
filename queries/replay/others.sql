-- replay: others
-- grain: one row per (match_id, frame, actor_id) of every other road user within others_range_m of the ego
-- reads: replay_windows, pair_tracks, tracks
-- params: $others_range_m
select
    w.match_id,
    o.frame,
    o.actor_id,
    o.kind,
    o.x_m,
    o.y_m,
    o.heading_rad,
    o.length_m,
    o.width_m
from replay_windows as w
inner join pair_tracks as e
    on w.drive_id = e.drive_id
    and w.ego_id = e.actor_id
    and e.frame between w.first_frame and w.last_frame
inner join tracks as o
    on w.drive_id = o.drive_id
    and e.frame = o.frame
    and o.actor_id <> w.ego_id
    and o.actor_id <> w.actor_id
    and (o.x_m - e.x_m) * (o.x_m - e.x_m) + (o.y_m - e.y_m) * (o.y_m - e.y_m) <= $others_range_m * $others_range_m
order by w.match_id, o.actor_id, o.frame
