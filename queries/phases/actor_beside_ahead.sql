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
--
-- How: only the pairs in which the actor is ever ahead in the ego's lane need its frames there; the others' frames
-- have no last or next frame in the lane, so each condition read from them holds. Those pairs' frames ahead are
-- counted in one window sort (frames_in_lane: how many so far were in the lane), and the last and next frame in the
-- lane are the lane frames numbered frames_in_lane and frames_in_lane + 1 (equi-joins, not more window
-- aggregates). A stretch of lane frames without a gap has one frame - frames_in_lane.
with

lane_pairs as (
    -- the pairs in which the actor is ahead in the ego's lane at some frame
    select distinct drive_key, ego_key, actor_key
    from relations
    where dx_m > 0 and same_lane
),

counted as (
    -- their frames ahead, with how many of them so far were in the ego's lane. Only the frames ahead count: a frame
    -- at which the actor is not ahead ends its stay in the ego's lane like a gap in its frames does, and is never
    -- in the ego's path
    select
        r.drive_key,
        r.ego_key,
        r.actor_key,
        r.frame,
        r.lane_run,
        r.same_lane,
        r.actor_lane_id,
        not r.same_lane and r.adjacent_side is not null as beside,
        not r.same_lane and r.adjacent_side is null as away,
        abs(r.dy_m) <= $max_cut_in_lateral_offset_m as near_centre,
        count(case when r.same_lane then 1 end) over (
            partition by r.drive_key, r.ego_key, r.actor_key order by r.frame
            rows between unbounded preceding and current row
        ) as frames_in_lane
    from relations as r
    inner join lane_pairs as p
        on r.drive_key = p.drive_key and r.ego_key = p.ego_key and r.actor_key = p.actor_key
    where r.dx_m > 0
),

in_lane as (
    -- the frames ahead in the ego's lane, numbered (frames_in_lane), each with its stretch: consecutive frames in the
    -- lane, without a gap or a frame out of it, share frame - frames_in_lane
    select
        drive_key,
        ego_key,
        actor_key,
        frames_in_lane,
        frame,
        lane_run,
        actor_lane_id,
        frame - frames_in_lane as stretch,
        near_centre
    from counted
    where same_lane
),

stretch_paths as (
    -- per stretch in one lane run, its last frame with the actor's centre within max_cut_in_lateral_offset of the
    -- ego's side to side: a stay that begins at a frame of the stretch reaches the ego's path iff it is not earlier
    select
        drive_key,
        ego_key,
        actor_key,
        stretch,
        lane_run,
        max(case when near_centre then frame end) as last_in_path_frame
    from in_lane
    group by drive_key, ego_key, actor_key, stretch, lane_run
),

per_frame as (
    -- per frame of those pairs:
    --   last_in_lane_frame  the actor's last frame ahead in the ego's lane so far in this lane run (the last one so
    --                       far, if its lane run is this one; the lane run only grows with the frame)
    --   left_lane_id        the lane the actor was in then
    --   entry_frame         the first frame from this one on at which it is ahead in the ego's lane (at the phase's
    --                       frames the actor is beside, not in the lane, so it is the next one), with its stretch
    select
        c.drive_key,
        c.ego_key,
        c.actor_key,
        c.frame,
        c.beside,
        c.away,
        case when last.lane_run = c.lane_run then last.frame end as last_in_lane_frame,
        last.actor_lane_id as left_lane_id,
        entry.frame as entry_frame,
        entry.stretch as entry_stretch,
        entry.lane_run as entry_lane_run
    from counted as c
    left join in_lane as last
        on c.drive_key = last.drive_key and c.ego_key = last.ego_key and c.actor_key = last.actor_key
        and c.frames_in_lane = last.frames_in_lane
    left join in_lane as entry
        on c.drive_key = entry.drive_key and c.ego_key = entry.ego_key and c.actor_key = entry.actor_key
        and c.frames_in_lane + case when c.same_lane then 0 else 1 end = entry.frames_in_lane
),

beside_after_in as (
    -- the frames beside the ego, out of its lane, after the actor was in it in this lane run, with the lane it left
    select b.drive_key, b.ego_key, b.actor_key, b.frame, b.last_in_lane_frame, d.map_id, b.left_lane_id
    from per_frame as b
    inner join drive_inputs as d
        on b.drive_key = d.drive_key
    where b.beside and b.last_in_lane_frame is not null
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

out_frames as (
    -- the frames at which the actor was clearly out of the ego's lane since its last frame there: beside the ego
    -- and farther than the tolerance from the lane it left, or neither in the lane nor beside it
    select b.drive_key, b.ego_key, b.actor_key, b.last_in_lane_frame, b.frame
    from beside_after_in as b
    left join near_left_lane as n
        on b.drive_key = n.drive_key and b.ego_key = n.ego_key and b.actor_key = n.actor_key and b.frame = n.frame
    where n.frame is null
    union all
    select drive_key, ego_key, actor_key, last_in_lane_frame, frame
    from per_frame
    where away and last_in_lane_frame is not null
),

first_out as (
    -- per stay out of the ego's lane (the frames after the same last_in_lane_frame), the first of them
    select drive_key, ego_key, actor_key, last_in_lane_frame, min(frame) as first_out_frame
    from out_frames
    group by drive_key, ego_key, actor_key, last_in_lane_frame
),

checked as (
    -- every frame ahead; a pair without a frame in the ego's lane has no per_frame row (no last or next frame in it)
    select
        r.*,
        r.ego_lane_id as ego_lane_now_id,
        a.entry_frame,
        a.last_in_lane_frame,
        a.entry_frame is null or (entry.lane_run = r.lane_run and line.lane_id is not null) as ego_keeps_lane,
        a.last_in_lane_frame is null or coalesce(o.first_out_frame <= r.frame, false) as actor_left_ego_lane,
        -- the actor reaches its path (last_in_path_frame) from the entry frame without leaving the ego's lane run or
        -- lane, or a gap in its frames between them: in the entry frame's stretch and lane run
        a.entry_frame is null or a.entry_frame <= path.last_in_path_frame as actor_in_ego_path
    from relations as r
    inner join drive_inputs as d
        on r.drive_key = d.drive_key
    left join per_frame as a
        on r.drive_key = a.drive_key and r.ego_key = a.ego_key and r.actor_key = a.actor_key and r.frame = a.frame
    left join ego_lanes as entry
        on r.drive_key = entry.drive_key and r.ego_key = entry.ego_key and a.entry_frame = entry.frame
    left join lane_line as line
        on d.map_id = line.map_id and r.ego_lane_id = line.lane_id and entry.lane_id = line.line_lane_id
    left join stretch_paths as path
        on r.drive_key = path.drive_key and r.ego_key = path.ego_key and r.actor_key = path.actor_key
        and a.entry_stretch = path.stretch and a.entry_lane_run = path.lane_run
    left join first_out as o
        on r.drive_key = o.drive_key and r.ego_key = o.ego_key and r.actor_key = o.actor_key
        and a.last_in_lane_frame = o.last_in_lane_frame
    where r.dx_m > 0
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
