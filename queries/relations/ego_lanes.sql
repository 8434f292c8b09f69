-- relations: ego_lanes
-- grain: one row per (drive_id, ego_id, frame): the ego's lane (the lane its centre is in) and its lane run
-- reads: egos, tracks, actor_lanes, track_lanes, drive_inputs, lane_neighbours, lane_line
-- params: $lane_calculation_tolerance_length_m
--
-- A lane run is a stretch the ego drives in one lane. It ends at a lane change:
--   1. the ego's lane becomes a lane beside the lane it had (lane_neighbours: a same-direction
--      neighbour, or the neighbour's successor or predecessor at a segment boundary): a transition. Lanes are
--      compared between consecutive samples of the ego, so frames missing in between (a dropped frame) do not
--      hide a transition: it is dated at the first frame seen in the new lane;
--   2. the change is confirmed if, after the transition, the ego is in a lane and more than
--      lane_calculation_tolerance_length away from the old lane and from the lanes that continue it (its
--      successors and predecessors): the keep_lane tolerance. It is dated at the transition, the frame at
--      which the ego's centre crossed into the new lane. The lane may meanwhile have moved on to the
--      next segment, so a lane change across a segment boundary still counts;
--   3. if the ego's lane returns to the old lane (or its continuation) first, there was no change, and
--      that return is not a transition of its own (so a flicker across the line never counts as a change back).
-- Moving on to a successor lane (a new road segment, a lane inside a junction) is not a lane change.
--
--   lane_id           the ego's lane: the lane its centre is in at that frame (actor_lanes), by the same rule as
--                     every actor's lane, so "same lane" and "beside" compare two lanes found alike. The tolerance
--                     above decides only whether a crossing is a lane change (a new lane run: keep_lane()), never
--                     which lane the ego is in: an ego whose centre drives 0.5 m over the line for seconds is in
--                     the lane its centre is in, as a car behind it at the same offset is
--   lane_change_side  the side the ego moved to, on the frame of the change (the first frame of a lane run)
--   lane_run          how many lane changes the ego made up to this frame
--   drive_key, ego_key  integer keys of the drive and the ego (tracks.drive_key, actor_key): the steps join and
--                       window on them; drive_id and ego_id are for people
with

ego_lane_distances as (
    -- the egos' rows of track_lanes (every lane within 3 m), picked out once: old_lane looks up the old lane's
    -- distance in them
    select tl.drive_key, tl.actor_key as ego_key, tl.frame, tl.lane_id, tl.dist_m
    from track_lanes as tl
    inner join egos as e
        on tl.drive_key = e.drive_key and tl.actor_key = e.ego_key
),

ego_rows as (
    select
        t.drive_key,
        t.actor_key as ego_key,
        t.drive_id,
        t.actor_id as ego_id,
        t.frame,
        t.t_s,
        al.lane_id
    from tracks as t
    inner join egos as e
        on t.drive_key = e.drive_key and t.actor_key = e.ego_key
    left join actor_lanes as al
        on t.drive_key = al.drive_key and t.actor_key = al.actor_key and t.frame = al.frame
),

islands as (
    select
        *,
        frame - row_number() over (
            partition by drive_key, ego_key, coalesce(lane_id, '') order by frame
        ) as island
    from ego_rows
),

runs as (
    select
        drive_key,
        ego_key,
        lane_id,
        island,
        min(frame) as run_start_frame,
        max(frame) as run_end_frame
    from islands
    group by drive_key, ego_key, lane_id, island
),

runs_with_previous as (
    select
        *,
        -- the previous run ends at the ego's previous sample, however many frames are missing in between
        lag(lane_id) over (partition by drive_key, ego_key order by run_start_frame) as previous_lane_id
    from runs
),

transitions as (
    -- the ego's best lane becomes a lane beside the one it had: a lane change may be under way
    select
        r.drive_key,
        r.ego_key,
        d.map_id,
        r.run_start_frame as transition_frame,
        r.previous_lane_id as from_lane_id,
        r.lane_id as to_lane_id,
        n.side
    from runs_with_previous as r
    inner join drive_inputs as d
        on r.drive_key = d.drive_key
    inner join lane_neighbours as n
        on d.map_id = n.map_id and r.previous_lane_id = n.lane_id and r.lane_id = n.near_lane_id
),

last_transition as (
    -- every ego frame with the frame of the last transition at or before it: transitions happen at ego frames,
    -- so the running max of the frames that have one is the last of them (a running max and a join back run on
    -- every engine, where last_value(... ignore nulls) does not parse on Polars SQL)
    select
        e.drive_key,
        e.ego_key,
        e.frame,
        e.lane_id,
        max(tr.transition_frame) over (
            partition by e.drive_key, e.ego_key order by e.frame rows between unbounded preceding and current row
        ) as transition_frame
    from ego_rows as e
    left join transitions as tr
        on e.drive_key = tr.drive_key and e.ego_key = tr.ego_key and e.frame = tr.transition_frame
),

pending as (
    -- every ego frame with the last transition before it (over segment boundaries the best lane's id may
    -- change again without a new transition)
    select
        lt.drive_key,
        lt.ego_key,
        lt.frame,
        lt.lane_id,
        tr.map_id,
        lt.transition_frame,
        tr.from_lane_id,
        tr.side
    from last_transition as lt
    left join transitions as tr
        on lt.drive_key = tr.drive_key and lt.ego_key = tr.ego_key and lt.transition_frame = tr.transition_frame
),

old_lane as (
    -- per frame after a transition: is the ego (back) in the lane it came from, and how far from it is it
    select
        p.drive_key,
        p.ego_key,
        p.frame,
        p.lane_id,
        p.transition_frame,
        p.side,
        max(case when p.lane_id = l.line_lane_id then 1 else 0 end) as back_in_old_lane,
        min(tl.dist_m) as old_lane_dist_m
    from pending as p
    inner join lane_line as l
        on p.map_id = l.map_id and p.from_lane_id = l.lane_id
    left join ego_lane_distances as tl
        on p.drive_key = tl.drive_key and p.ego_key = tl.ego_key and p.frame = tl.frame and l.line_lane_id = tl.lane_id
    where p.transition_frame is not null
    group by p.drive_key, p.ego_key, p.frame, p.lane_id, p.transition_frame, p.side
),

changes as (
    -- the first frame, before any return to the old lane, in which the ego is in a lane and more than the
    -- tolerance away from the old lane (and from the lanes that continue it). The return is a window over the
    -- transition's frames, not a second reading of old_lane joined back (which Spark evaluated differently from
    -- DuckDB once nothing else read it)
    select
        drive_key,
        ego_key,
        transition_frame,
        side,
        min(frame) as frame
    from (
        select
            *,
            min(case when back_in_old_lane = 1 and frame > transition_frame then frame end) over (
                partition by drive_key, ego_key, transition_frame
            ) as return_frame
        from old_lane
    ) as o
    where lane_id is not null
        and (return_frame is null or frame < return_frame)
        and back_in_old_lane = 0
        and (old_lane_dist_m is null or old_lane_dist_m > $lane_calculation_tolerance_length_m)
    group by drive_key, ego_key, transition_frame, side
),

classed as (
    -- a transition back into the lane line the previous transition came from, before that one was counted as a
    -- change, is the ego returning (a flicker across the line), not a new transition. In a chain of such returns
    -- they alternate: the first is a transition, the second its return, the third a transition again, ...
    select
        *,
        row_number() over (partition by drive_key, ego_key, chain order by transition_frame) % 2 = 0 as is_return
    from (
        select
            *,
            sum(case when back then 0 else 1 end) over (
                partition by drive_key, ego_key order by transition_frame
                rows between unbounded preceding and current row
            ) as chain
        from (
            select
                t.drive_key,
                t.ego_key,
                t.transition_frame,
                coalesce(c.frame is null and l.line_lane_id is not null, false) as back
            from (
                select
                    *,
                    lag(transition_frame) over (partition by drive_key, ego_key order by transition_frame)
                        as previous_frame,
                    lag(from_lane_id) over (partition by drive_key, ego_key order by transition_frame)
                        as previous_from_lane_id
                from transitions
            ) as t
            left join lane_line as l
                on t.map_id = l.map_id and t.previous_from_lane_id = l.lane_id and t.to_lane_id = l.line_lane_id
            left join changes as c
                on t.drive_key = c.drive_key and t.ego_key = c.ego_key and t.previous_frame = c.transition_frame
        ) as flagged
    ) as chained
),

counted as (
    -- the lane changes: the changes of the transitions that are not returns
    select c.*
    from changes as c
    inner join classed as k
        on c.drive_key = k.drive_key and c.ego_key = k.ego_key and c.transition_frame = k.transition_frame
    where not k.is_return
)

select
    e.drive_id,
    e.ego_id,
    p.frame,
    e.t_s,
    p.lane_id,
    c.side as lane_change_side,
    count(c.frame) over (
        partition by p.drive_key, p.ego_key order by p.frame rows between unbounded preceding and current row
    ) as lane_run,
    p.drive_key,
    p.ego_key
from pending as p
inner join ego_rows as e
    on p.drive_key = e.drive_key and p.ego_key = e.ego_key and p.frame = e.frame
left join counted as c
    on p.drive_key = c.drive_key and p.ego_key = c.ego_key and p.frame = c.transition_frame
