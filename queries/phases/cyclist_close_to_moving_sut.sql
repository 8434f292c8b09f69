-- phase: cyclist_close_to_moving_sut
-- grain: one row per (drive_id, ego_id, actor_id, island, piece): consecutive frames in which a cyclist is
--        close to the moving ego, cut into pieces of at most max_phase_duration
-- reads: relations, tracks, drive_inputs
-- params: $sut_minimal_speed_mps, $min_distance_from_cyclist_m, $max_distance_from_cyclist_m,
--         $max_phase_duration_s
--
-- Per frame: the ego's speed >= sut_minimal_speed, the actor is a cyclist, and the closest box-to-box
-- distance is in [min_distance_from_cyclist, max_distance_from_cyclist].
-- "The scenario should last at most max_phase_duration": an episode that lasts longer is cut into
-- consecutive pieces, each spanning at most max_phase_duration (floor(max/dt) + 1 frames), so no part of
-- it is lost; the last piece may be shorter.
with

close as (
    select
        r.drive_id,
        r.ego_id,
        r.actor_id,
        r.frame,
        r.t_s,
        d.dt_s
    from relations as r
    inner join tracks as e
        on r.drive_id = e.drive_id and r.ego_id = e.actor_id and r.frame = e.frame
    inner join drive_inputs as d
        on r.drive_id = d.drive_id
    where r.actor_kind = 'cyclist'
        and e.speed_mps >= $sut_minimal_speed_mps
        and r.box_distance_m >= $min_distance_from_cyclist_m
        and r.box_distance_m <= $max_distance_from_cyclist_m
),

islands as (
    select
        *,
        frame - row_number() over (partition by drive_id, ego_id, actor_id order by frame) as island
    from close
),

pieces as (
    select
        *,
        floor(
            (frame - min(frame) over (partition by drive_id, ego_id, actor_id, island))
            / (floor($max_phase_duration_s / nullif(dt_s, 0) + 1e-9) + 1)
        ) as piece
    from islands
)

select
    drive_id,
    ego_id,
    actor_id,
    min(frame) as start_frame,
    max(frame) as end_frame,
    min(t_s) as start_s,
    max(t_s) as end_s
from pieces
group by drive_id, ego_id, actor_id, island, piece
