-- relations: ego_lanes
-- grain: one row per (drive_id, ego_id, frame): the ego's lane (the lane of its lane run), its best lane, and its
--        lane run
-- reads: egos, tracks, actor_lanes, track_lanes, drive_inputs, lane_neighbours, lane_line
-- params: $lane_calculation_tolerance_length_m
--
-- A lane run is a stretch the ego drives in one lane. It ends at a lane change:
--   1. the ego's best lane becomes a lane beside the lane it had (lane_neighbours: a same-direction
--      neighbour, or the neighbour's successor or predecessor at a segment boundary): a transition. Lanes are
--      compared between consecutive samples of the ego, so frames missing in between (a dropped frame) do not
--      hide a transition: it is dated at the first frame seen in the new lane;
--   2. the change is confirmed if, after the transition, the ego is in a lane and more than
--      lane_calculation_tolerance_length away from the old lane and from the lanes that continue it (its
--      successors and predecessors): the keep_lane tolerance. It is dated at the transition, the frame at
--      which the ego's centre crossed into the new lane. The best lane may meanwhile have moved on to the
--      next segment, so a lane change across a segment boundary still counts;
--   3. if the ego's best lane returns to the old lane (or its continuation) first, there was no change, and
--      that return is not a transition of its own (so a flicker across the line never counts as a change back).
-- Moving on to a successor lane (a new road segment, a lane inside a junction) is not a lane change.
--
--   best_lane_id      the lane the ego's centre is in at that frame (actor_lanes)
--   lane_id           the ego's lane: its best lane, except after a transition that is never confirmed (the
--                     centre crossed the line and came back within the tolerance: jitter, a drift), when it is
--                     still the lane it came from. Every relation to the ego's lane (relations.same_lane,
--                     adjacent_side) uses this column, so "same lane", "beside" and the lane change agree frame
--                     by frame: a leader is in the ego's lane up to the frame before the change, and beside it
--                     from the frame of the change on
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

returns as (
    select
        drive_key,
        ego_key,
        transition_frame,
        min(frame) as return_frame
    from old_lane
    where back_in_old_lane = 1 and frame > transition_frame
    group by drive_key, ego_key, transition_frame
),

changes as (
    -- the first frame, before any return to the old lane, in which the ego is in a lane and more than the
    -- tolerance away from the old lane (and from the lanes that continue it)
    select
        o.drive_key,
        o.ego_key,
        o.transition_frame,
        o.side,
        min(o.frame) as frame
    from old_lane as o
    left join returns as r
        on o.drive_key = r.drive_key and o.ego_key = r.ego_key and o.transition_frame = r.transition_frame
    where o.lane_id is not null
        and (r.return_frame is null or o.frame < r.return_frame)
        and o.back_in_old_lane = 0
        and (o.old_lane_dist_m is null or o.old_lane_dist_m > $lane_calculation_tolerance_length_m)
    group by o.drive_key, o.ego_key, o.transition_frame, o.side
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
),

resolved as (
    -- a transition confirmed by a lane change takes effect at once (the change is dated at the transition: the
    -- frame the ego's centre crossed into the new lane); so does a return; an unconfirmed transition holds the
    -- old lane until the ego returns to it (or for good, until the next transition)
    select
        k.drive_key,
        k.ego_key,
        k.transition_frame,
        case
            when k.is_return or c.frame is not null then k.transition_frame
            else r.return_frame
        end as resolved_frame
    from classed as k
    left join counted as c
        on k.drive_key = c.drive_key and k.ego_key = c.ego_key and k.transition_frame = c.transition_frame
    left join returns as r
        on k.drive_key = r.drive_key and k.ego_key = r.ego_key and k.transition_frame = r.transition_frame
)

select
    e.drive_id,
    e.ego_id,
    p.frame,
    e.t_s,
    case
        when p.transition_frame is not null and (v.resolved_frame is null or p.frame < v.resolved_frame)
            then p.from_lane_id
        else p.lane_id
    end as lane_id,
    p.lane_id as best_lane_id,
    c.side as lane_change_side,
    count(c.frame) over (
        partition by p.drive_key, p.ego_key order by p.frame rows between unbounded preceding and current row
    ) as lane_run,
    p.drive_key,
    p.ego_key
from pending as p
inner join ego_rows as e
    on p.drive_key = e.drive_key and p.ego_key = e.ego_key and p.frame = e.frame
left join resolved as v
    on p.drive_key = v.drive_key and p.ego_key = v.ego_key and p.transition_frame = v.transition_frame
left join counted as c
    on p.drive_key = c.drive_key and p.ego_key = c.ego_key and p.frame = c.transition_frame
