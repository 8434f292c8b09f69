-- frames: unprotected_left_turn_frames (the scenario's `frames` step, read by its four phase queries)
-- grain: one row per (drive_id, ego_id, ego_passage, actor_id, actor_passage, frame) at which the ego and a
--        related actor are near or in the same junction: every measured value the four phases test, and every
--        condition (phases/stop_in_green_light.sql, ... take the conjunction of theirs)
-- reads: crossing_pairs, junction_frames, passages, encroachments, tracks, drive_inputs, traffic_lights,
--        traffic_light_states
-- params: $max_gap_s, $kinds_csv, $min_offset_from_junction_start_m, $max_offset_from_junction_start_m,
--         $min_offset_from_junction_end_m, $max_offset_from_junction_end_m,
--         $ref_car_max_distance_from_junction_m, $stopping_car_speed_limit_mps,
--         $max_offset_from_traffic_light_m, $encroachment_start_buffer, $encroachment_end_buffer
--
-- Definitions (docs/semantics.md, "unprotected_left_turn_with_yield_and_traffic_light"):
--   ego_offset_from_junction_start_m, ...   offsets along each actor's own path (junction_frames)
--   ego_turn                                 the turn of the ego's passage through the junction (passages.turn)
--   ego_speed_mps                            the ego's speed averaged over its frame and the two rows either
--                                            side (0.5 s at 10 Hz): a perceived speed's noise (0.1 m/s) must
--                                            not make a car creeping just above the stop limit stop for a frame
--   light_state                              state of the light that governs the ego's movement: a light of
--                                            the ego's entry lane whose direction includes the ego's turn (or
--                                            governs every movement); green if any such light is green; NULL
--                                            when no light governs it; 'unknown' when the data has no state
--   light_in_range                           the ego is at most max_offset_from_traffic_light before the stop
--                                            line (the junction start) or already in the junction it controls
--   traversal_relative_direction             <entry leg>_to_<exit leg> of the actor, each leg classed against
--                                            the ego's inbound heading (see leg classes below)
--   occupancy                                the stretch of its own path (its centre's s_m) along which a
--                                            box overlaps the encroachment area (encroachments.*_occupancy_*)
--   actor_in_encroachment                    the actor's centre is inside its occupancy after the buffers
--                                            cut encroachment_start_buffer and encroachment_end_buffer of
--                                            its length from the start and the end
--   in / out frame                           the frame from which a box stays in or past the area (its s_m
--                                            at least the occupancy's start), and past it (beyond its end):
--                                            the frame after its last one short of it; on a path that only
--                                            moves forward, its first frame in (past) the area
--   actor_first                              the actor's box leaves the area before the ego's enters it
--   ego_yields                               actor_first, and the ego's box has not reached the area yet: the
--                                            ego is giving the right of way
--   actor_approaching                        the actor's front is within [min, max]_offset_from_junction_start
--                                            of its junction start, or past it and its box not yet at the
--                                            ego's path (before actor_reach_frame)
--   ego_has_stopped                          the ego stood (ego_stopped) at a frame of the current stretch of
--                                            frames at which phase 1's other conditions all hold: it stops,
--                                            then gives the right of way, pulling forward or standing
--   actor_finishing                          actor_crossing, or the actor is the last of kinds to leave the
--                                            encroachment area (its box) of those that reached it by the time
--                                            the ego sets off (or left it at most max_gap before that one), from
--                                            that frame until the ego sets off: the car the ego waited for
--   ego_turning                              ego_in_junction, after the ego's last stand (ego_stopped) before
--                                            its box reaches the encroachment area of an actor it may have
--                                            waited for (the latest over them; without one, this actor's):
--                                            the turn, from the moment the ego sets off
--   actor_crossing                           the actor is past the start of its (buffered) encroachment and
--                                            at most max_offset_from_junction_end past the junction end
--   actor_reaches_junction_end               the actor gets to min_offset_from_junction_end from the junction
--                                            end before the ego's box enters the area: it finishes crossing
--   pet_s                                    post-encroachment time: the second box's first frame in the
--                                            area minus the first box's first frame after it; NULL when the
--                                            boxes were in the area at the same time or one never crossed it
-- Leg classes: d = the leg's inbound heading minus the ego's inbound heading, wrapped into (-180, 180]
-- degrees; |d| < 45 parallel (the ego's own leg), |d| > 135 opposite, -135 < d < -45 left, 45 < d < 135
-- right. An actor's entry leg's inbound heading is its heading before entry; its exit leg's is its heading
-- after exit turned by 180 degrees. Unknown when a heading is missing (entry or exit not observed).
with

pair_frames as (
    -- every frame of the ego near or in a junction, for each actor that came near or into the same junction
    -- within the relation range while the ego was there (crossing_pairs); the actor's columns are NULL at the
    -- frames it is farther from the junction
    select
        c.drive_id,
        c.ego_id,
        c.actor_id,
        c.drive_key,
        c.ego_key,
        c.actor_key,
        k.kind as actor_kind,
        e.frame,
        e.t_s,
        c.ego_passage,
        c.actor_passage,
        c.junction_id,
        e.s_m as ego_s_m,
        a.s_m as actor_s_m,
        e.offset_from_junction_start_m as ego_offset_from_junction_start_m,
        e.offset_from_junction_end_m as ego_offset_from_junction_end_m,
        a.offset_from_junction_start_m as actor_offset_from_junction_start_m,
        a.offset_from_junction_end_m as actor_offset_from_junction_end_m
    from crossing_pairs as c
    inner join junction_frames as e
        on c.drive_id = e.drive_id and c.ego_id = e.actor_id and c.ego_passage = e.passage
    inner join (select drive_id, actor_id, min(kind) as kind from tracks group by drive_id, actor_id) as k
        on c.drive_id = k.drive_id and c.actor_id = k.actor_id
    left join junction_frames as a
        on c.drive_id = a.drive_id and c.actor_id = a.actor_id and c.actor_passage = a.passage
        and e.frame = a.frame
),

occupancy as (
    -- each encroachment's occupancy stretches, on the ego's and on the actor's own path (logiq_sql/matching/encroachment.py)
    select
        x.*,
        x.ego_occupancy_from_s_m as ego_occupancy_lo_m,
        x.ego_occupancy_to_s_m as ego_occupancy_hi_m,
        x.actor_occupancy_from_s_m as actor_occupancy_lo_m,
        x.actor_occupancy_to_s_m as actor_occupancy_hi_m
    from encroachments as x
),

crossing_rows as (
    -- the ego's and the actor's frames on their passages, beside each encroachment, and where the box is against
    -- its occupancy stretch (two equi-joins unioned, not one join with an OR: Polars joins on equalities only)
    select
        o.drive_id,
        o.ego_id,
        o.ego_passage,
        o.actor_id,
        o.actor_passage,
        'ego' as who,
        e.frame,
        e.s_m >= o.ego_occupancy_lo_m as reached,
        e.s_m > o.ego_occupancy_hi_m as passed
    from occupancy as o
    inner join junction_frames as e
        on o.drive_id = e.drive_id and o.ego_id = e.actor_id and o.ego_passage = e.passage
    union all
    select
        o.drive_id,
        o.ego_id,
        o.ego_passage,
        o.actor_id,
        o.actor_passage,
        'actor' as who,
        e.frame,
        e.s_m >= o.actor_occupancy_lo_m as reached,
        e.s_m > o.actor_occupancy_hi_m as passed
    from occupancy as o
    inner join junction_frames as e
        on o.drive_id = e.drive_id and o.actor_id = e.actor_id and o.actor_passage = e.passage
),

crossing_last as (
    -- each box's last frame short of the area, and its last frame not yet past it
    select
        drive_id,
        ego_id,
        ego_passage,
        actor_id,
        actor_passage,
        who,
        max(case when not reached then frame end) as last_short_frame,
        max(case when not passed then frame end) as last_unpassed_frame
    from crossing_rows
    group by drive_id, ego_id, ego_passage, actor_id, actor_passage, who
),

crossing_first as (
    -- the frame from which each box stays in or past the area (in), and past it (out): a position that jitters
    -- across the area's edge while the car waits or creeps there enters it when it stops coming back
    select
        r.drive_id,
        r.ego_id,
        r.ego_passage,
        r.actor_id,
        r.actor_passage,
        r.who,
        min(case when r.reached and (l.last_short_frame is null or r.frame > l.last_short_frame) then r.frame end)
            as in_frame,
        min(case when r.passed and (l.last_unpassed_frame is null or r.frame > l.last_unpassed_frame) then r.frame end)
            as out_frame
    from crossing_rows as r
    inner join crossing_last as l
        on r.drive_id = l.drive_id and r.ego_id = l.ego_id and r.ego_passage = l.ego_passage
        and r.actor_id = l.actor_id and r.actor_passage = l.actor_passage and r.who = l.who
    group by r.drive_id, r.ego_id, r.ego_passage, r.actor_id, r.actor_passage, r.who
),

crossing_times as (
    select
        drive_id,
        ego_id,
        ego_passage,
        actor_id,
        actor_passage,
        max(case when who = 'ego' then in_frame end) as ego_in_frame,
        max(case when who = 'ego' then out_frame end) as ego_out_frame,
        max(case when who = 'actor' then in_frame end) as actor_in_frame,
        max(case when who = 'actor' then out_frame end) as actor_out_frame
    from crossing_first
    group by drive_id, ego_id, ego_passage, actor_id, actor_passage
),

crossing as (
    select
        o.*,
        c.ego_in_frame,
        c.ego_out_frame,
        c.actor_in_frame,
        c.actor_out_frame,
        c.actor_out_frame <= c.ego_in_frame as actor_first,
        case
            when c.actor_out_frame <= c.ego_in_frame then (c.ego_in_frame - c.actor_out_frame) * d.dt_s
            when c.ego_out_frame <= c.actor_in_frame then (c.actor_in_frame - c.ego_out_frame) * d.dt_s
        end as pet_s
    from occupancy as o
    inner join crossing_times as c
        on o.drive_id = c.drive_id and o.ego_id = c.ego_id and o.ego_passage = c.ego_passage
        and o.actor_id = c.actor_id and o.actor_passage = c.actor_passage
    inner join drive_inputs as d
        on o.drive_id = d.drive_id
),

legs as (
    select
        f.drive_id,
        f.ego_id,
        f.ego_passage,
        f.actor_id,
        f.actor_passage,
        pe.turn as ego_turn,
        pe.entry_lane_id as ego_entry_lane_id,
        degrees(atan2(sin(pa.entry_heading_rad - pe.entry_heading_rad),
                      cos(pa.entry_heading_rad - pe.entry_heading_rad))) as entry_d_deg,
        degrees(atan2(sin(pa.exit_heading_rad + pi() - pe.entry_heading_rad),
                      cos(pa.exit_heading_rad + pi() - pe.entry_heading_rad))) as exit_d_deg
    from (select distinct drive_id, ego_id, ego_passage, actor_id, actor_passage from pair_frames) as f
    inner join passages as pe
        on f.drive_id = pe.drive_id and f.ego_id = pe.actor_id and f.ego_passage = pe.passage
    inner join passages as pa
        on f.drive_id = pa.drive_id and f.actor_id = pa.actor_id and f.actor_passage = pa.passage
),

leg_classes as (
    select
        *,
        case
            when entry_d_deg is null then null
            when abs(entry_d_deg) < 45 then 'parallel'
            when abs(entry_d_deg) > 135 then 'opposite'
            when entry_d_deg < 0 then 'left'
            else 'right'
        end as actor_entry_leg,
        case
            when exit_d_deg is null then null
            when abs(exit_d_deg) < 45 then 'parallel'
            when abs(exit_d_deg) > 135 then 'opposite'
            when exit_d_deg < 0 then 'left'
            else 'right'
        end as actor_exit_leg
    from legs
),

ego_passage_lights as (
    -- the lights that govern the ego's movement on each passage
    select distinct
        pe.drive_id,
        pe.actor_id as ego_id,
        pe.passage as ego_passage,
        tl.light_id
    from passages as pe
    inner join traffic_lights as tl
        on pe.map_id = tl.map_id and pe.entry_lane_id = tl.lane_id
    where tl.direction is null or instr(',' || tl.direction || ',', ',' || pe.turn || ',') > 0
),

ego_lights as (
    select
        f.drive_id,
        f.ego_id,
        f.ego_passage,
        f.frame,
        case
            when count(gl.light_id) = 0 then null
            when max(case when s.state = 'green' then 1 else 0 end) = 1 then 'green'
            when count(s.state) = 0 then 'unknown'
            else min(s.state)
        end as light_state
    from (select distinct drive_id, ego_id, ego_passage, frame from pair_frames) as f
    inner join passages as pe
        on f.drive_id = pe.drive_id and f.ego_id = pe.actor_id and f.ego_passage = pe.passage
    left join ego_passage_lights as gl
        on f.drive_id = gl.drive_id and f.ego_id = gl.ego_id and f.ego_passage = gl.ego_passage
    left join traffic_light_states as s
        on f.drive_id = s.drive_id and gl.light_id = s.light_id and f.frame = s.frame
    group by f.drive_id, f.ego_id, f.ego_passage, f.frame
),

ego_speed_rows as (
    -- the ego's speed at each of its frames near the junction and at the two rows either side (lag and lead, not a
    -- sliding frame: Polars SQL has none)
    select
        f.drive_id,
        f.ego_id,
        f.ego_passage,
        f.frame,
        t.speed_mps as v0,
        lag(t.speed_mps, 2) over w as v_2,
        lag(t.speed_mps, 1) over w as v_1,
        lead(t.speed_mps, 1) over w as v1,
        lead(t.speed_mps, 2) over w as v2
    from (select distinct drive_id, ego_id, ego_passage, frame from pair_frames) as f
    inner join tracks as t
        on f.drive_id = t.drive_id and f.ego_id = t.actor_id and f.frame = t.frame
    window w as (partition by f.drive_id, f.ego_id, f.ego_passage order by f.frame)
),

ego_speeds as (
    -- the mean of the speeds that are known among the five
    select
        drive_id,
        ego_id,
        ego_passage,
        frame,
        case when n > 0 then total / n end as ego_speed_mps
    from (
        select
            drive_id,
            ego_id,
            ego_passage,
            frame,
            coalesce(v_2, 0.0) + coalesce(v_1, 0.0) + coalesce(v0, 0.0) + coalesce(v1, 0.0) + coalesce(v2, 0.0)
                as total,
            case when v_2 is null then 0 else 1 end + case when v_1 is null then 0 else 1 end
                + case when v0 is null then 0 else 1 end + case when v1 is null then 0 else 1 end
                + case when v2 is null then 0 else 1 end as n
        from ego_speed_rows
    ) as sums
),

measured as (
    select
        f.*,
        v.ego_speed_mps,
        g.ego_turn,
        l.light_state,
        g.actor_entry_leg,
        g.actor_exit_leg,
        coalesce(g.actor_entry_leg || '_to_' || g.actor_exit_leg, 'unknown') as traversal_relative_direction,
        c.area_m2 as encroachment_area_m2,
        c.actor_first,
        c.pet_s,
        c.ego_in_frame as ego_encroachment_frame,
        c.actor_in_frame as actor_reach_frame,
        c.actor_out_frame as actor_clear_frame,
        min(case when f.actor_offset_from_junction_end_m >= $min_offset_from_junction_end_m then f.frame end) over (
            partition by f.drive_id, f.ego_id, f.ego_passage, f.actor_id, f.actor_passage
        ) as actor_end_frame,
        c.actor_occupancy_lo_m + $encroachment_start_buffer * (c.actor_occupancy_hi_m - c.actor_occupancy_lo_m)
            as actor_encroachment_from_s_m,
        c.actor_occupancy_hi_m - $encroachment_end_buffer * (c.actor_occupancy_hi_m - c.actor_occupancy_lo_m)
            as actor_encroachment_to_s_m
    from pair_frames as f
    inner join ego_speeds as v
        on f.drive_id = v.drive_id and f.ego_id = v.ego_id and f.ego_passage = v.ego_passage and f.frame = v.frame
    inner join leg_classes as g
        on f.drive_id = g.drive_id and f.ego_id = g.ego_id and f.ego_passage = g.ego_passage
        and f.actor_id = g.actor_id and f.actor_passage = g.actor_passage
    inner join ego_lights as l
        on f.drive_id = l.drive_id and f.ego_id = l.ego_id and f.ego_passage = l.ego_passage and f.frame = l.frame
    left join crossing as c
        on f.drive_id = c.drive_id and f.ego_id = c.ego_id and f.ego_passage = c.ego_passage
        and f.actor_id = c.actor_id and f.actor_passage = c.actor_passage
),

conditions as (
    select
        *,
        instr($kinds_csv, ',' || actor_kind || ',') > 0 as actor_kind_ok,
        coalesce(ego_turn = 'left', false) as ego_turns_left,
        coalesce(ego_offset_from_junction_start_m between $min_offset_from_junction_start_m
            and $max_offset_from_junction_start_m, false) as ego_near_junction_start,
        coalesce(ego_speed_mps <= $stopping_car_speed_limit_mps, false) as ego_stopped,
        coalesce(ego_offset_from_junction_start_m >= -$max_offset_from_traffic_light_m
            and coalesce(ego_offset_from_junction_end_m <= 0, true), false) as light_in_range,
        coalesce(light_state = 'green', false) as light_green,
        -- near its junction start, or already inside the junction and its box not yet at the ego's path (the
        -- encroachment area): on a skewed or large junction, or when the ego brakes late, the car it gives way
        -- to is more than max_offset_from_junction_start into the junction when the ego stands
        coalesce(actor_offset_from_junction_start_m between $min_offset_from_junction_start_m
            and $max_offset_from_junction_start_m
            or (actor_offset_from_junction_start_m >= 0 and frame < actor_reach_frame), false) as actor_approaching,
        coalesce(actor_offset_from_junction_start_m >= 0
            and actor_offset_from_junction_end_m <= $ref_car_max_distance_from_junction_m, false)
            as actor_inside_junction,
        coalesce(actor_entry_leg <> 'parallel', false) as actor_from_other_entry,
        coalesce(actor_first and frame < ego_encroachment_frame, false) as ego_yields,
        coalesce(actor_s_m between actor_encroachment_from_s_m and actor_encroachment_to_s_m, false)
            as actor_in_encroachment,
        coalesce(actor_s_m >= actor_encroachment_from_s_m
            and actor_offset_from_junction_end_m <= $max_offset_from_junction_end_m, false) as actor_crossing,
        coalesce(actor_end_frame < ego_encroachment_frame, false) as actor_reaches_junction_end,
        coalesce(ego_offset_from_junction_start_m >= $min_offset_from_junction_start_m
            and ego_offset_from_junction_end_m <= 0, false) as ego_in_junction
    from measured
),

waiting as (
    -- phase 1's conditions but the stop itself, and the last frame (so far) at which they did not all hold
    select
        *,
        actor_kind_ok and ego_turns_left and ego_near_junction_start and light_in_range and light_green
            and actor_approaching and ego_yields as ego_waiting,
        max(case when not (actor_kind_ok and ego_turns_left and ego_near_junction_start and light_in_range
                           and light_green and actor_approaching and ego_yields) then frame end) over (
            partition by drive_id, ego_id, ego_passage, actor_id, actor_passage order by frame
            rows between unbounded preceding and current row
        ) as waiting_since_frame,
        -- the ego's last stand before its box reaches the encroachment area (before it leaves the junction when
        -- the paths share no area): it sets off on its turn at the next frame
        max(case when ego_stopped and (ego_encroachment_frame is null or frame < ego_encroachment_frame)
                 then frame end) over (
            partition by drive_id, ego_id, ego_passage, actor_id, actor_passage
        ) as ego_last_stop_frame
    from conditions
),

candidates as (
    -- the actors the ego may have waited for: of kinds, from another entry, crossing its path first, and on that
    -- path (the box reached the area) by the time the ego sets off from its last stand before it
    select
        *,
        actor_kind_ok and actor_from_other_entry and coalesce(actor_first, false)
            and coalesce(actor_reach_frame <= ego_last_stop_frame + 1, false) as waited_candidate
    from waiting
),

clearing as (
    -- over every actor of the ego's passage, the frame at which the last candidate leaves the ego's path: the
    -- actor the ego waited for, with any that left it at most max_gap earlier (two oncoming lanes passing
    -- together). Reached, not left, by the set-off: a driver sets off as the car it waited for is clearing its
    -- path, so "left before the set-off" turned on a frame or two and credited the car before it. And the
    -- ego's last stand before the turn: its latest stand before a candidate's area, so that an ego that rolls
    -- into the junction behind one car and stands there for the oncoming ones sets off on its turn once
    select
        w.*,
        max(case when w.waited_candidate then w.actor_clear_frame end) over (
            partition by w.drive_id, w.ego_id, w.ego_passage
        ) - floor($max_gap_s / nullif(d.dt_s, 0) + 1e-9) as waited_for_from_frame,
        max(case when w.waited_candidate then w.ego_last_stop_frame end) over (
            partition by w.drive_id, w.ego_id, w.ego_passage
        ) as ego_turn_stop_frame
    from candidates as w
    inner join drive_inputs as d
        on w.drive_id = d.drive_id
)

select
    *,
    -- the ego stopped at some frame of the current stretch of waiting (the stop starts phase 1; it then gives
    -- the right of way, pulling forward to its waiting position or not)
    coalesce(max(case when ego_waiting and ego_stopped then frame end) over (
        partition by drive_id, ego_id, ego_passage, actor_id, actor_passage order by frame
        rows between unbounded preceding and current row
    ) > coalesce(waiting_since_frame, -1), false) as ego_has_stopped,
    ego_in_junction and coalesce(frame > coalesce(ego_turn_stop_frame, ego_last_stop_frame), true) as ego_turning,
    -- crossing, or, for the last actor the ego waited for, past the encroachment area until the ego sets off
    actor_crossing or coalesce(actor_clear_frame >= waited_for_from_frame
                               and actor_clear_frame <= ego_turn_stop_frame + 1 and frame >= actor_clear_frame
                               and frame <= ego_turn_stop_frame, false) as actor_finishing
from clearing
