-- phase: actor_beside_ahead (cut_in_ahead_of_ego, phase 1; logiq_sql's own scenario, not a LogIQ page)
-- grain: one row per (drive_id, ego_id, actor_id, frame) at which the actor is ahead of the ego (dx_m > 0): the
--        phase contract (docs/scenarios.md)
-- reads: relations, ego_lanes, drive_inputs, lane_line, track_lanes (joined and windowed on the integer keys)
-- params: $kinds_csv, $min_distance_from_sut_in_time_units_s, $max_distance_from_sut_in_time_units_s,
--         $lane_calculation_tolerance_length_m, $max_cut_in_lateral_offset_m
--
-- Conditions (holds = all of them):
--   actor_kind_ok      the actor is of one of the kinds
--   actor_ahead        entirely ahead of the ego's front bumper (dx > 0 and lon_gap > 0)
--   actor_beside       the actor's lane is beside the ego's lane (adjacent_side, from lane_neighbours)
--   headway_in_range   time headway (gap / ego speed) in [min_distance_from_sut_in_time_units,
--                      max_distance_from_sut_in_time_units]
--   ego_keeps_lane     the actor comes into the ego's lane, not the ego into the actor's: at the next frame at
--                      which the actor is ahead in the ego's lane (same_lane), the ego is in the same lane run and
--                      in the lane it has now or one that continues it (lane_line). An ego that drifts over the
--                      line towards the actor, without a counted lane change, does not make the actor cut in.
--                      True when the actor is not in the ego's lane again later
--   actor_left_ego_lane  the actor comes from the lane beside: if it was ahead in the ego's lane earlier in the
--                      ego's lane run, it has since been more than lane_calculation_tolerance_length away from
--                      the lane it was in then and the lanes that continue it (lane_line), or neither in the
--                      ego's lane nor beside it. The ego's keep_lane rule read for the actor: a car that drifts
--                      over the line into the lane beside and back, never further, has not left the ego's lane,
--                      so its return is no cut-in (the two parallel lanelets of a double left turn swap a car's
--                      label while it drives on)
--   actor_in_ego_path  the cut-in ends with the actor in the ego's path: between its next frame ahead in the ego's
--                      lane (entry_frame) and the end of that stay (the first frame after it at which the actor is
--                      not ahead in the ego's lane, or the last before a gap in its frames, within the ego's lane
--                      run), its centre comes within max_cut_in_lateral_offset (1.5 m) of the ego's centre side
--                      to side in the ego's frame (|dy_m|) at least once. A lane label alone is not a cut-in: where
--                      lanelets overlap (a double left turn) a car's label can become the ego's while it drives on
--                      beside it, 3 m and more to the side. True when the actor is not in the ego's lane again
--                      later (the phase then does not chain anyway)
-- segment = the ego's lane run: the ego keeps its lane while the actor cuts in.
with

ahead as (
    -- the frames at which the actor is ahead: the phase's grain, and all that its conditions read of the relation
    select r.*, r.ego_lane_id as ego_lane_now_id
    from relations as r
    where r.dx_m > 0
),

per_frame as (
    -- per frame, read forwards in one sort by actor (the ego's lane run only grows with the frame):
    --   last_in_lane_frame     the actor's last frame ahead in the ego's lane so far in this lane run (the last one
    --                          so far in any lane run, if that is this one)
    --   last_not_beside_frame  its last frame so far neither in the ego's lane nor beside it
    --   entry_frame            the first frame from this one on at which it is ahead in the ego's lane (at the
    --                          phase's frames the actor is beside, not in the lane, so it is the next one)
    --   in_path_frame          the first frame from this one on at which it is ahead in the ego's lane with its
    --                          centre within max_cut_in_lateral_offset of the ego's side to side
    --   frames_in_lane         how many frames so far it was ahead in the ego's lane: between two frames in the lane
    --                          it stayed in the lane throughout iff this count grew by their distance in frames
    -- Only the frames ahead count: a frame at which the actor is not ahead ends its stay in the ego's lane like a
    -- gap in its frames does, and is never in the ego's path
    select
        *,
        case when max(case when same_lane then lane_run end) over (
            partition by drive_key, ego_key, actor_key order by frame
            rows between unbounded preceding and current row
        ) = lane_run then max(case when same_lane then frame end) over (
            partition by drive_key, ego_key, actor_key order by frame
            rows between unbounded preceding and current row
        ) end as last_in_lane_frame,
        max(case when not same_lane and adjacent_side is null then frame end) over (
            partition by drive_key, ego_key, actor_key order by frame
            rows between unbounded preceding and current row
        ) as last_not_beside_frame,
        min(case when same_lane then frame end) over (
            partition by drive_key, ego_key, actor_key order by frame
            rows between current row and unbounded following
        ) as entry_frame,
        min(case when same_lane and abs(dy_m) <= $max_cut_in_lateral_offset_m then frame end) over (
            partition by drive_key, ego_key, actor_key order by frame
            rows between current row and unbounded following
        ) as in_path_frame,
        count(case when same_lane then 1 end) over (
            partition by drive_key, ego_key, actor_key order by frame
            rows between unbounded preceding and current row
        ) as frames_in_lane
    from ahead
),

beside_after_in as (
    -- the frames beside the ego, out of its lane, after the actor was in it in this lane run, with the lane the
    -- actor was in then: the lane it left (a join back: last_value(... ignore nulls) does not run on every engine)
    select
        b.drive_key, b.ego_key, b.actor_key, b.frame, b.last_in_lane_frame, d.map_id, i.actor_lane_id as left_lane_id
    from per_frame as b
    inner join per_frame as i
        on b.drive_key = i.drive_key and b.ego_key = i.ego_key and b.actor_key = i.actor_key
        and b.last_in_lane_frame = i.frame
    inner join drive_inputs as d
        on b.drive_key = d.drive_key
    where b.adjacent_side is not null and not b.same_lane
),

beside_lanes as (
    -- the lanes the actor is within the tolerance of at those frames, found on the integer keys first. Distinct
    -- (the rows are distinct already) so that the engine cannot join the lane ids of every map first
    select distinct b.drive_key, b.ego_key, b.actor_key, b.frame, b.map_id, b.left_lane_id, tl.lane_id
    from beside_after_in as b
    inner join track_lanes as tl
        on b.drive_key = tl.drive_key and b.actor_key = tl.actor_key and b.frame = tl.frame
    where tl.dist_m <= $lane_calculation_tolerance_length_m
),

near_left_lane as (
    -- of those, the frames at which the actor is within the tolerance of the lane it left or a lane that continues
    -- it (the ego's keep_lane rule: the lane it came from and its lane line)
    select b.drive_key, b.ego_key, b.actor_key, b.frame
    from beside_lanes as b
    inner join lane_line as line
        on b.map_id = line.map_id and b.left_lane_id = line.lane_id and b.lane_id = line.line_lane_id
    group by b.drive_key, b.ego_key, b.actor_key, b.frame
),

first_far as (
    -- per stay out of the ego's lane (the frames after the same last_in_lane_frame), the first frame beside the ego
    -- and farther than the tolerance from the lane the actor left: with the frames neither in the lane nor beside
    -- it (last_not_beside_frame), the frames at which the actor was clearly out of the ego's lane
    select b.drive_key, b.ego_key, b.actor_key, b.last_in_lane_frame, min(b.frame) as first_far_frame
    from beside_after_in as b
    left join near_left_lane as n
        on b.drive_key = n.drive_key and b.ego_key = n.ego_key and b.actor_key = n.actor_key and b.frame = n.frame
    where n.frame is null
    group by b.drive_key, b.ego_key, b.actor_key, b.last_in_lane_frame
),

stays as (
    -- the frames ahead in the ego's lane, where a cut-in's stay can begin (entry_frame) and end in its path
    select drive_key, ego_key, actor_key, frame, lane_run, in_path_frame, frames_in_lane
    from per_frame
    where same_lane
),

checked as (
    select
        a.*,
        a.entry_frame is null or (entry.lane_run = a.lane_run and line.lane_id is not null) as ego_keeps_lane,
        -- out of the ego's lane since the last frame in it: a frame neither in nor beside it, or beside it but
        -- away from the lane it left
        a.last_in_lane_frame is null or coalesce(a.last_not_beside_frame > a.last_in_lane_frame, false)
            or coalesce(far.first_far_frame <= a.frame, false) as actor_left_ego_lane,
        -- the actor reaches its path (in_path_frame) from the entry frame without leaving the ego's lane run or
        -- lane, or a gap in its frames between them
        a.entry_frame is null
            or (path.lane_run = stay.lane_run
                and path.frames_in_lane - stay.frames_in_lane = path.frame - stay.frame) as actor_in_ego_path
    from per_frame as a
    inner join drive_inputs as d
        on a.drive_key = d.drive_key
    left join ego_lanes as entry
        on a.drive_key = entry.drive_key and a.ego_key = entry.ego_key and a.entry_frame = entry.frame
    left join lane_line as line
        on d.map_id = line.map_id and a.ego_lane_now_id = line.lane_id and entry.lane_id = line.line_lane_id
    left join stays as stay
        on a.drive_key = stay.drive_key and a.ego_key = stay.ego_key and a.actor_key = stay.actor_key
        and a.entry_frame = stay.frame
    left join stays as path
        on stay.drive_key = path.drive_key and stay.ego_key = path.ego_key and stay.actor_key = path.actor_key
        and stay.in_path_frame = path.frame
    left join first_far as far
        on a.drive_key = far.drive_key and a.ego_key = far.ego_key and a.actor_key = far.actor_key
        and a.last_in_lane_frame = far.last_in_lane_frame
),

conditions as (
    select
        drive_id,
        ego_id,
        actor_id,
        drive_key,
        ego_key,
        actor_key,
        frame,
        t_s,
        lane_run as segment,
        instr($kinds_csv, ',' || actor_kind || ',') > 0 as actor_kind_ok,
        lon_gap_m > 0 as actor_ahead,
        adjacent_side is not null as actor_beside,
        coalesce(time_headway_s >= $min_distance_from_sut_in_time_units_s
            and time_headway_s <= $max_distance_from_sut_in_time_units_s, false) as headway_in_range,
        ego_keeps_lane,
        actor_left_ego_lane,
        coalesce(actor_in_ego_path, false) as actor_in_ego_path,
        actor_kind,
        lon_gap_m,
        adjacent_side,
        time_headway_s,
        ego_lane_now_id as ego_lane_id,
        actor_lane_id,
        entry_frame,
        last_in_lane_frame
    from checked
)

-- holds is exactly the AND of the conditions above (logiq-sql lint checks it against the scenario file)
select
    *,
    actor_kind_ok and actor_ahead and actor_beside and headway_in_range and ego_keeps_lane and actor_left_ego_lane
        and actor_in_ego_path as holds
from conditions
