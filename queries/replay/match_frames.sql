-- replay: match_frames
-- grain: one row per (match_id, frame) of the window where the ego has a track row
-- reads: replay_windows, pair_tracks, pair_relations
-- params: none
--
-- The ego's and the actor's boxes (actor columns NULL where it is not tracked), the actor's gap, time
-- headway and TTC as the relation query defines them (lon_gap_m, time_headway_s, ttc_s; NULL where
-- undefined), and the headway follower_vehicle tests (phases/follower_vehicle.sql: follow_gap_m / actor speed,
-- follow_gap_m = greatest(lon_gap_m + lat_gap_m, box_distance_m)); the replay shows the one the scenario tests.
select
    w.match_id,
    e.frame,
    e.t_s,
    e.x_m as ego_x_m,
    e.y_m as ego_y_m,
    e.heading_rad as ego_heading_rad,
    e.length_m as ego_length_m,
    e.width_m as ego_width_m,
    e.speed_mps as ego_speed_mps,
    a.x_m as actor_x_m,
    a.y_m as actor_y_m,
    a.heading_rad as actor_heading_rad,
    a.length_m as actor_length_m,
    a.width_m as actor_width_m,
    a.speed_mps as actor_speed_mps,
    r.lon_gap_m,
    r.time_headway_s,
    case when a.speed_mps > 0 then greatest(r.lon_gap_m + r.lat_gap_m, r.box_distance_m) / a.speed_mps end
        as follow_headway_s,
    r.ttc_s
from replay_windows as w
inner join pair_tracks as e
    on w.drive_id = e.drive_id
    and w.ego_id = e.actor_id
    and e.frame between w.first_frame and w.last_frame
left join pair_tracks as a
    on w.drive_id = a.drive_id
    and w.actor_id = a.actor_id
    and e.frame = a.frame
left join pair_relations as r
    on w.drive_id = r.drive_id
    and w.ego_id = r.ego_id
    and w.actor_id = r.actor_id
    and e.frame = r.frame
order by w.match_id, e.frame
