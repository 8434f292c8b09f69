-- relations: ego_lanes
-- grain: one row per (drive_id, ego_id, frame): the ego's lane and its lane run
-- reads: egos, tracks, actor_lanes, track_lanes, drive_inputs, lanes
-- params: $lane_calculation_tolerance_length_m
--
-- A lane run is a stretch the ego drives in one lane. It ends at a lane change: the ego's best lane
-- becomes the left or right same-direction neighbour of the lane it had, and the ego has moved more than
-- lane_calculation_tolerance_length away from that old lane (the keep_lane tolerance). Moving on to a
-- successor lane (a new road segment, a lane inside a junction) is not a lane change.
with

ego_rows as (
    select
        t.drive_id,
        t.actor_id as ego_id,
        t.frame,
        t.t_s,
        al.lane_id
    from tracks as t
    inner join egos as e
        on t.drive_id = e.drive_id and t.actor_id = e.ego_id
    left join actor_lanes as al
        on t.drive_id = al.drive_id and t.actor_id = al.actor_id and t.frame = al.frame
),

islands as (
    select
        *,
        frame - row_number() over (
            partition by drive_id, ego_id, coalesce(lane_id, '') order by frame
        ) as island
    from ego_rows
),

runs as (
    select
        drive_id,
        ego_id,
        lane_id,
        island,
        min(frame) as run_start_frame,
        max(frame) as run_end_frame
    from islands
    group by drive_id, ego_id, lane_id, island
),

runs_with_previous as (
    select
        *,
        lag(lane_id) over (partition by drive_id, ego_id order by run_start_frame) as previous_lane_id,
        lag(run_end_frame) over (partition by drive_id, ego_id order by run_start_frame) as previous_end_frame
    from runs
),

neighbour_runs as (
    select
        r.*,
        case when old.left_lane_id = r.lane_id then 'left' else 'right' end as side
    from runs_with_previous as r
    inner join drive_inputs as d
        on r.drive_id = d.drive_id
    inner join lanes as old
        on d.map_id = old.map_id and r.previous_lane_id = old.lane_id
    where r.previous_end_frame = r.run_start_frame - 1
        and (
            (old.left_lane_id = r.lane_id and old.left_same_direction)
            or (old.right_lane_id = r.lane_id and old.right_same_direction)
        )
),

changes as (
    select
        n.drive_id,
        n.ego_id,
        n.previous_lane_id as from_lane_id,
        n.lane_id as to_lane_id,
        n.side,
        min(i.frame) as frame
    from neighbour_runs as n
    inner join islands as i
        on n.drive_id = i.drive_id and n.ego_id = i.ego_id
        and i.frame between n.run_start_frame and n.run_end_frame
    left join track_lanes as tl
        on i.drive_id = tl.drive_id and i.ego_id = tl.actor_id and i.frame = tl.frame
        and n.previous_lane_id = tl.lane_id
    where tl.dist_m is null or tl.dist_m > $lane_calculation_tolerance_length_m
    group by n.drive_id, n.ego_id, n.previous_lane_id, n.lane_id, n.side, n.run_start_frame
)

select
    e.drive_id,
    e.ego_id,
    e.frame,
    e.t_s,
    e.lane_id,
    c.side as lane_change_side,
    count(c.frame) over (
        partition by e.drive_id, e.ego_id order by e.frame rows between unbounded preceding and current row
    ) as lane_run
from ego_rows as e
left join changes as c
    on e.drive_id = c.drive_id and e.ego_id = c.ego_id and e.frame = c.frame
