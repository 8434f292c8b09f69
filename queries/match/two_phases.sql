-- match: two_phases
-- grain: one row per match of a two-phase scenario: phase 1 directly followed by phase 2, with both phase
--        intervals (p1_*, p2_*) and the match interval [start, end] = [p1 start, p2 end]
-- reads: phase_1, phase_2, tracks
-- params: $phase_1_min_duration_s, $phase_1_max_duration_s, $phase_2_min_duration_s, $phase_2_max_duration_s
--         (the scenario's phase duration parameters; a max of NULL means no limit)
--
-- Phases are sequential: phase 2 starts at the frame after phase 1 ends, for the same (ego, actor).
-- A phase that lasts longer than its maximum is cut where it does not touch the other phase: phase 1 keeps its
-- last max seconds before the transition, phase 2 its first max seconds after it, so every transition is
-- found once, however long the drive stayed in either phase. Both phases must then last at least their
-- minimum (end_s - start_s, like every duration here). Timestamps are compared with a 1 us tolerance, so a
-- 3 s limit keeps 3 s of 0.1 s samples whatever the floating-point rounding of t_s.
with

joined as (
    select
        p1.drive_id,
        p1.ego_id,
        p1.actor_id,
        p1.start_frame as p1_first_frame,
        p1.end_frame as p1_end_frame,
        p1.end_s as p1_end_s,
        p2.start_frame as p2_start_frame,
        p2.end_frame as p2_last_frame,
        p2.start_s as p2_start_s
    from phase_1 as p1
    inner join phase_2 as p2
        on p1.drive_id = p2.drive_id and p1.ego_id = p2.ego_id and p1.actor_id = p2.actor_id
        and p2.start_frame = p1.end_frame + 1
),

trimmed as (
    -- the frames of the ego within the maximum duration of each phase, counted from the transition (frame and
    -- t_s grow together, so the least frame has the least t_s)
    select
        j.drive_id,
        j.ego_id,
        j.actor_id,
        j.p1_end_frame,
        j.p1_end_s,
        j.p2_start_frame,
        j.p2_start_s,
        min(e.frame) as p1_start_frame,
        min(e.t_s) as p1_start_s,
        max(e.frame) as p2_end_frame,
        max(e.t_s) as p2_end_s
    from joined as j
    inner join tracks as e
        on j.drive_id = e.drive_id and j.ego_id = e.actor_id
        and e.frame between j.p1_first_frame and j.p2_last_frame
    where (
            e.frame > j.p1_end_frame or $phase_1_max_duration_s is null
            or e.t_s >= j.p1_end_s - $phase_1_max_duration_s - 1e-6
        )
        and (
            e.frame < j.p2_start_frame or $phase_2_max_duration_s is null
            or e.t_s <= j.p2_start_s + $phase_2_max_duration_s + 1e-6
        )
    group by j.drive_id, j.ego_id, j.actor_id, j.p1_end_frame, j.p1_end_s, j.p2_start_frame, j.p2_start_s
)

select
    drive_id,
    ego_id,
    actor_id,
    p1_start_frame as start_frame,
    p2_end_frame as end_frame,
    p1_start_s as start_s,
    p2_end_s as end_s,
    p1_start_frame,
    p1_end_frame,
    p1_start_s,
    p1_end_s,
    p2_start_frame,
    p2_end_frame,
    p2_start_s,
    p2_end_s
from trimmed
where p1_end_s - p1_start_s >= $phase_1_min_duration_s - 1e-6
    and p2_end_s - p2_start_s >= $phase_2_min_duration_s - 1e-6
