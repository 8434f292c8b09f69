-- staging: tracks
-- grain: one row per (drive_id, actor_id, frame), canonical columns, kinematics completed
-- reads: tracks_raw (a reader's rows; heading_rad, speed_mps, accel_mps2 may be NULL)
-- params: none
--
-- What is derived, only where the source left it NULL:
--   velocity     central difference of positions over the neighbouring samples (one-sided at track ends):
--                v = (p[i+1] - p[i-1]) / (t[i+1] - t[i-1])
--   heading_rad  direction of that velocity when the actor moves faster than 0.5 m/s; while slower, the
--                last moving heading (else the first one, else 0): a standing car keeps its heading
--   speed_mps    velocity projected on the heading (negative when reversing); NULL for a one-sample track
--   accel_mps2   central difference of speed, then a centred 5-sample moving average (the smoothing)
with

ordered as (
    select
        *,
        lag(x_m) over w as x_prev,
        lead(x_m) over w as x_next,
        lag(y_m) over w as y_prev,
        lead(y_m) over w as y_next,
        lag(t_s) over w as t_prev,
        lead(t_s) over w as t_next
    from tracks_raw
    window w as (partition by drive_id, actor_id order by frame)
),

velocity as (
    select
        *,
        (coalesce(x_next, x_m) - coalesce(x_prev, x_m))
            / nullif(coalesce(t_next, t_s) - coalesce(t_prev, t_s), 0) as vx_mps,
        (coalesce(y_next, y_m) - coalesce(y_prev, y_m))
            / nullif(coalesce(t_next, t_s) - coalesce(t_prev, t_s), 0) as vy_mps
    from ordered
),

motion_heading as (
    select
        *,
        case
            when vx_mps * vx_mps + vy_mps * vy_mps > 0.25 then atan2(vy_mps, vx_mps)
        end as moving_heading_rad
    from velocity
),

headed as (
    select
        *,
        coalesce(
            heading_rad,
            moving_heading_rad,
            last_value(moving_heading_rad ignore nulls) over (
                partition by drive_id, actor_id order by frame
                rows between unbounded preceding and current row
            ),
            first_value(moving_heading_rad ignore nulls) over (
                partition by drive_id, actor_id order by frame
                rows between unbounded preceding and unbounded following
            ),
            0.0
        ) as heading_filled_rad
    from motion_heading
),

sped as (
    select
        *,
        -- NULL for a track of one sample: its speed is undefined, not 0
        coalesce(speed_mps, vx_mps * cos(heading_filled_rad) + vy_mps * sin(heading_filled_rad)) as speed_filled_mps
    from headed
),

speed_diff as (
    select
        *,
        (coalesce(lead(speed_filled_mps) over w, speed_filled_mps)
            - coalesce(lag(speed_filled_mps) over w, speed_filled_mps))
            / nullif(coalesce(lead(t_s) over w, t_s) - coalesce(lag(t_s) over w, t_s), 0) as raw_accel_mps2
    from sped
    window w as (partition by drive_id, actor_id order by frame)
)

select
    drive_id,
    actor_id,
    kind,
    is_ego,
    frame,
    t_s,
    x_m,
    y_m,
    heading_filled_rad as heading_rad,
    speed_filled_mps as speed_mps,
    coalesce(
        accel_mps2,
        avg(raw_accel_mps2) over (
            partition by drive_id, actor_id order by frame rows between 2 preceding and 2 following
        )
    ) as accel_mps2,
    length_m,
    width_m
from speed_diff
