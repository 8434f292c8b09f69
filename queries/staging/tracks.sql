-- staging: tracks
-- grain: one row per row of tracks_raw, in its order: the row's row_key and its completed heading_rad, speed_mps
--        and accel_mps2 (ingest stores them with the row's other columns, which it passes by itself)
-- reads: tracks_raw (a reader's rows in (drive_id, actor_id, frame) order, with track_no the same for every
--        row of one (drive_id, actor_id) and different from its neighbours'; heading_rad, speed_mps, accel_mps2
--        may be NULL; drive_key, actor_key, row_key: the integer keys ingest assigns, schema.TRACK_KEYS)
-- params: none
--
-- What is derived, only where the source left it NULL:
--   velocity     central difference of positions over the neighbouring samples (one-sided at track ends):
--                v = (p[i+1] - p[i-1]) / (t[i+1] - t[i-1])
--   heading_rad  direction of that velocity when the actor moves faster than 0.5 m/s; while slower, the
--                last moving heading (else the first one, else 0): a standing car keeps its heading
--   speed_mps    velocity projected on the heading (negative when reversing); NULL for a one-sample track
--   accel_mps2   central difference of speed, then a centred 5-sample moving average (the smoothing)
--
-- Speed: the rows arrive in track order, so every window runs over that order (an empty OVER (), which DuckDB
-- guarantees keeps the input order of one table: docs "Order Preservation") and a neighbour counts only when it
-- has the row's track_no. Partitions by drive and actor would sort on strings, several times the CPU of these
-- windows for identical results (benchmarks/README.md). DuckDB only: Spark keeps no input order. Only the columns
-- the windows need go through them (each window holds every column it passes on: the row's other columns, passed
-- through too, doubled the query's CPU).
with

neighbours as (
    select
        *,
        case when lag(track_no) over w = track_no then lag(x_m) over w end as x_prev,
        case when lead(track_no) over w = track_no then lead(x_m) over w end as x_next,
        case when lag(track_no) over w = track_no then lag(y_m) over w end as y_prev,
        case when lead(track_no) over w = track_no then lead(y_m) over w end as y_next,
        case when lag(track_no) over w = track_no then lag(t_s) over w end as t_prev,
        case when lead(track_no) over w = track_no then lead(t_s) over w end as t_next
    from tracks_raw
    window w as ()
),

velocity as (
    select
        *,
        (coalesce(x_next, x_m) - coalesce(x_prev, x_m))
            / nullif(coalesce(t_next, t_s) - coalesce(t_prev, t_s), 0) as vx_mps,
        (coalesce(y_next, y_m) - coalesce(y_prev, y_m))
            / nullif(coalesce(t_next, t_s) - coalesce(t_prev, t_s), 0) as vy_mps
    from neighbours
),

motion_heading as (
    select
        *,
        case
            when vx_mps * vx_mps + vy_mps * vy_mps > 0.25 then atan2(vy_mps, vx_mps)
        end as moving_heading_rad,
        -- the track of the row that has a moving heading (NULL exactly where moving_heading_rad is NULL)
        case when vx_mps * vx_mps + vy_mps * vy_mps > 0.25 then track_no end as moving_track_no
    from velocity
),

heading_neighbours as (
    -- the last moving heading up to this row and the first from this row on, each with its track
    select
        *,
        last_value(moving_heading_rad ignore nulls) over before_row as last_moving_rad,
        last_value(moving_track_no ignore nulls) over before_row as last_moving_track_no,
        first_value(moving_heading_rad ignore nulls) over from_row as first_moving_rad,
        first_value(moving_track_no ignore nulls) over from_row as first_moving_track_no
    from motion_heading
    window
        before_row as (rows between unbounded preceding and current row),
        from_row as (rows between current row and unbounded following)
),

headed as (
    select
        *,
        coalesce(
            heading_rad,
            moving_heading_rad,
            case when last_moving_track_no = track_no then last_moving_rad end,
            -- no moving sample up to here: the first one of the track (none before, so the next one is it)
            case when first_moving_track_no = track_no then first_moving_rad end,
            0.0
        ) as heading_filled_rad
    from heading_neighbours
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
        (coalesce(case when lead(track_no) over w = track_no then lead(speed_filled_mps) over w end, speed_filled_mps)
            - coalesce(case when lag(track_no) over w = track_no then lag(speed_filled_mps) over w end, speed_filled_mps))
            / nullif(coalesce(t_next, t_s) - coalesce(t_prev, t_s), 0) as raw_accel_mps2
    from sped
    window w as ()
),

accel_window as (
    -- the raw accelerations of the two samples before and after, where they belong to the same track
    select
        *,
        case when lag(track_no, 2) over w = track_no then lag(raw_accel_mps2, 2) over w end as a_m2,
        case when lag(track_no, 1) over w = track_no then lag(raw_accel_mps2, 1) over w end as a_m1,
        case when lead(track_no, 1) over w = track_no then lead(raw_accel_mps2, 1) over w end as a_p1,
        case when lead(track_no, 2) over w = track_no then lead(raw_accel_mps2, 2) over w end as a_p2
    from speed_diff
    window w as ()
)

select
    row_key,
    heading_filled_rad as heading_rad,
    speed_filled_mps as speed_mps,
    coalesce(
        accel_mps2,
        -- the mean of the defined values among the five (NULL when none is)
        (coalesce(a_m2, 0) + coalesce(a_m1, 0) + coalesce(raw_accel_mps2, 0) + coalesce(a_p1, 0) + coalesce(a_p2, 0))
            / nullif(
                case when a_m2 is null then 0 else 1 end + case when a_m1 is null then 0 else 1 end
                + case when raw_accel_mps2 is null then 0 else 1 end + case when a_p1 is null then 0 else 1 end
                + case when a_p2 is null then 0 else 1 end, 0
            )
    ) as accel_mps2
from accel_window
