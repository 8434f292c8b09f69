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
--
-- How: joined and grouped on the integer keys (drive_key, ego_key, actor_key with the passages). What is the
-- pair's (kind, legs, encroachment) is found once per pair of passages and what is the ego's (speed, light) once
-- per ego frame, before the two meet at the pair's frames; the per-pair and per-passage values (actor_end_frame,
-- ego_last_stop_frame, the waited-for actor) are grouped minima and maxima, not windows over every frame; the one
-- running window (the stretches of waiting) sorts only the pairs with a frame of waiting.
with

actor_kinds as (
    -- each paired actor's kind (its least over its rows), from its rows of tracks alone
    select t.drive_key, t.actor_key, min(t.kind) as kind
    from tracks as t
    inner join (select distinct drive_key, actor_key from crossing_pairs) as a
        on t.drive_key = a.drive_key and t.actor_key = a.actor_key
    group by t.drive_key, t.actor_key
),

occupancy as (
    -- each encroachment's occupancy stretches, on the ego's and on the actor's own path
    -- (logiq_sql/matching/encroachment.py), with the pair's integer keys
    select
        x.*,
        c.drive_key,
        c.ego_key,
        c.actor_key,
        x.ego_occupancy_from_s_m as ego_occupancy_lo_m,
        x.ego_occupancy_to_s_m as ego_occupancy_hi_m,
        x.actor_occupancy_from_s_m as actor_occupancy_lo_m,
        x.actor_occupancy_to_s_m as actor_occupancy_hi_m
    from encroachments as x
    inner join (
        select distinct drive_id, ego_id, ego_passage, actor_id, actor_passage, drive_key, ego_key, actor_key
        from crossing_pairs
    ) as c
        on x.drive_id = c.drive_id and x.ego_id = c.ego_id and x.ego_passage = c.ego_passage
        and x.actor_id = c.actor_id and x.actor_passage = c.actor_passage
),

crossing_rows as (
    -- the ego's and the actor's frames on their passages, beside each encroachment, and where the box is against
    -- its occupancy stretch (two equi-joins unioned, not one join with an OR: Polars joins on equalities only)
    select
        o.drive_key,
        o.ego_key,
        o.ego_passage,
        o.actor_key,
        o.actor_passage,
        'ego' as who,
        e.frame,
        e.s_m >= o.ego_occupancy_lo_m as reached,
        e.s_m > o.ego_occupancy_hi_m as passed
    from occupancy as o
    inner join junction_frames as e
        on o.drive_key = e.drive_key and o.ego_key = e.actor_key and o.ego_passage = e.passage
    union all
    select
        o.drive_key,
        o.ego_key,
        o.ego_passage,
        o.actor_key,
        o.actor_passage,
        'actor' as who,
        e.frame,
        e.s_m >= o.actor_occupancy_lo_m as reached,
        e.s_m > o.actor_occupancy_hi_m as passed
    from occupancy as o
    inner join junction_frames as e
        on o.drive_key = e.drive_key and o.actor_key = e.actor_key and o.actor_passage = e.passage
),

crossing_last as (
    -- each box's last frame short of the area, and its last frame not yet past it
    select
        drive_key,
        ego_key,
        ego_passage,
        actor_key,
        actor_passage,
        who,
        max(case when not reached then frame end) as last_short_frame,
        max(case when not passed then frame end) as last_unpassed_frame
    from crossing_rows
    group by drive_key, ego_key, ego_passage, actor_key, actor_passage, who
),

crossing_first as (
    -- the frame from which each box stays in or past the area (in), and past it (out): a position that jitters
    -- across the area's edge while the car waits or creeps there enters it when it stops coming back
    select
        r.drive_key,
        r.ego_key,
        r.ego_passage,
        r.actor_key,
        r.actor_passage,
        r.who,
        min(case when r.reached and (l.last_short_frame is null or r.frame > l.last_short_frame) then r.frame end)
            as in_frame,
        min(case when r.passed and (l.last_unpassed_frame is null or r.frame > l.last_unpassed_frame) then r.frame end)
            as out_frame
    from crossing_rows as r
    inner join crossing_last as l
        on r.drive_key = l.drive_key and r.ego_key = l.ego_key and r.ego_passage = l.ego_passage
        and r.actor_key = l.actor_key and r.actor_passage = l.actor_passage and r.who = l.who
    group by r.drive_key, r.ego_key, r.ego_passage, r.actor_key, r.actor_passage, r.who
),

crossing_times as (
    select
        drive_key,
        ego_key,
        ego_passage,
        actor_key,
        actor_passage,
        max(case when who = 'ego' then in_frame end) as ego_in_frame,
        max(case when who = 'ego' then out_frame end) as ego_out_frame,
        max(case when who = 'actor' then in_frame end) as actor_in_frame,
        max(case when who = 'actor' then out_frame end) as actor_out_frame
    from crossing_first
    group by drive_key, ego_key, ego_passage, actor_key, actor_passage
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
        on o.drive_key = c.drive_key and o.ego_key = c.ego_key and o.ego_passage = c.ego_passage
        and o.actor_key = c.actor_key and o.actor_passage = c.actor_passage
    inner join drive_inputs as d
        on o.drive_key = d.drive_key
),

legs as (
    -- each pair's passages (crossing_pairs: one row per pair of passages)
    select
        f.drive_key,
        f.ego_key,
        f.ego_passage,
        f.actor_key,
        f.actor_passage,
        pe.turn as ego_turn,
        pe.entry_lane_id as ego_entry_lane_id,
        degrees(atan2(sin(pa.entry_heading_rad - pe.entry_heading_rad),
                      cos(pa.entry_heading_rad - pe.entry_heading_rad))) as entry_d_deg,
        degrees(atan2(sin(pa.exit_heading_rad + pi() - pe.entry_heading_rad),
                      cos(pa.exit_heading_rad + pi() - pe.entry_heading_rad))) as exit_d_deg
    from (select distinct drive_key, ego_key, ego_passage, actor_key, actor_passage from crossing_pairs) as f
    inner join passages as pe
        on f.drive_key = pe.drive_key and f.ego_key = pe.actor_key and f.ego_passage = pe.passage
    inner join passages as pa
        on f.drive_key = pa.drive_key and f.actor_key = pa.actor_key and f.actor_passage = pa.passage
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

pairs as (
    -- each pair of passages (crossing_pairs: an actor that came near or into the junction of an ego's passage
    -- within the relation range while the ego was there) with what is the pair's at every frame: the actor's
    -- kind, the legs, the encroachment
    select
        c.drive_id,
        c.ego_id,
        c.actor_id,
        c.drive_key,
        c.ego_key,
        c.actor_key,
        k.kind as actor_kind,
        c.ego_passage,
        c.actor_passage,
        c.junction_id,
        g.ego_turn,
        g.actor_entry_leg,
        g.actor_exit_leg,
        x.area_m2,
        x.actor_first,
        x.pet_s,
        x.ego_in_frame,
        x.actor_in_frame,
        x.actor_out_frame,
        x.actor_occupancy_lo_m,
        x.actor_occupancy_hi_m,
        instr($kinds_csv, ',' || k.kind || ',') > 0 as actor_kind_ok,
        coalesce(g.actor_entry_leg <> 'parallel', false) as actor_from_other_entry
    from crossing_pairs as c
    inner join actor_kinds as k
        on c.drive_key = k.drive_key and c.actor_key = k.actor_key
    inner join leg_classes as g
        on c.drive_key = g.drive_key and c.ego_key = g.ego_key and c.ego_passage = g.ego_passage
        and c.actor_key = g.actor_key and c.actor_passage = g.actor_passage
    left join crossing as x
        on c.drive_key = x.drive_key and c.ego_key = x.ego_key and c.ego_passage = x.ego_passage
        and c.actor_key = x.actor_key and c.actor_passage = x.actor_passage
),

ego_frames as (
    -- every frame of the ego near or in a junction, on its passages that have a pair
    select
        e.drive_key,
        e.actor_key as ego_key,
        e.passage as ego_passage,
        e.frame,
        e.t_s,
        e.s_m,
        e.offset_from_junction_start_m,
        e.offset_from_junction_end_m
    from junction_frames as e
    inner join (select distinct drive_key, ego_key, ego_passage from pairs) as p
        on e.drive_key = p.drive_key and e.actor_key = p.ego_key and e.passage = p.ego_passage
),

ego_passage_lights as (
    -- the lights that govern the ego's movement on each passage
    select distinct
        pe.drive_key,
        pe.drive_id,
        pe.actor_key as ego_key,
        pe.passage as ego_passage,
        tl.light_id
    from passages as pe
    inner join traffic_lights as tl
        on pe.map_id = tl.map_id and pe.entry_lane_id = tl.lane_id
    where tl.direction is null or instr(',' || tl.direction || ',', ',' || pe.turn || ',') > 0
),

ego_lights as (
    select
        f.drive_key,
        f.ego_key,
        f.ego_passage,
        f.frame,
        case
            when count(gl.light_id) = 0 then null
            when max(case when s.state = 'green' then 1 else 0 end) = 1 then 'green'
            when count(s.state) = 0 then 'unknown'
            else min(s.state)
        end as light_state
    from ego_frames as f
    left join ego_passage_lights as gl
        on f.drive_key = gl.drive_key and f.ego_key = gl.ego_key and f.ego_passage = gl.ego_passage
    left join traffic_light_states as s
        on gl.drive_id = s.drive_id and gl.light_id = s.light_id and f.frame = s.frame
    group by f.drive_key, f.ego_key, f.ego_passage, f.frame
),

ego_speed_rows as (
    -- the ego's speed at each of its frames near the junction and at the two rows either side (lag and lead, not a
    -- sliding frame: Polars SQL has none)
    select
        f.drive_key,
        f.ego_key,
        f.ego_passage,
        f.frame,
        t.speed_mps as v0,
        lag(t.speed_mps, 2) over w as v_2,
        lag(t.speed_mps, 1) over w as v_1,
        lead(t.speed_mps, 1) over w as v1,
        lead(t.speed_mps, 2) over w as v2
    from ego_frames as f
    inner join tracks as t
        on f.drive_key = t.drive_key and f.ego_key = t.actor_key and f.frame = t.frame
    window w as (partition by f.drive_key, f.ego_key, f.ego_passage order by f.frame)
),

ego_speeds as (
    -- the mean of the speeds that are known among the five
    select
        drive_key,
        ego_key,
        ego_passage,
        frame,
        case when n > 0 then total / n end as ego_speed_mps
    from (
        select
            drive_key,
            ego_key,
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

ego_measured as (
    -- the ego's values at each of those frames
    select
        f.*,
        v.ego_speed_mps,
        l.light_state
    from ego_frames as f
    inner join ego_speeds as v
        on f.drive_key = v.drive_key and f.ego_key = v.ego_key and f.ego_passage = v.ego_passage and f.frame = v.frame
    inner join ego_lights as l
        on f.drive_key = l.drive_key and f.ego_key = l.ego_key and f.ego_passage = l.ego_passage and f.frame = l.frame
),

measured as (
    -- every frame of the ego on a passage, for each actor of a pair of passages with it; the actor's columns are
    -- NULL at the frames it is farther from the junction
    select
        p.drive_id,
        p.ego_id,
        p.actor_id,
        p.drive_key,
        p.ego_key,
        p.actor_key,
        p.actor_kind,
        e.frame,
        e.t_s,
        p.ego_passage,
        p.actor_passage,
        p.junction_id,
        e.s_m as ego_s_m,
        a.s_m as actor_s_m,
        e.offset_from_junction_start_m as ego_offset_from_junction_start_m,
        e.offset_from_junction_end_m as ego_offset_from_junction_end_m,
        a.offset_from_junction_start_m as actor_offset_from_junction_start_m,
        a.offset_from_junction_end_m as actor_offset_from_junction_end_m,
        e.ego_speed_mps,
        p.ego_turn,
        e.light_state,
        p.actor_entry_leg,
        p.actor_exit_leg,
        coalesce(p.actor_entry_leg || '_to_' || p.actor_exit_leg, 'unknown') as traversal_relative_direction,
        p.area_m2 as encroachment_area_m2,
        p.actor_first,
        p.pet_s,
        p.ego_in_frame as ego_encroachment_frame,
        p.actor_in_frame as actor_reach_frame,
        p.actor_out_frame as actor_clear_frame,
        p.actor_occupancy_lo_m + $encroachment_start_buffer * (p.actor_occupancy_hi_m - p.actor_occupancy_lo_m)
            as actor_encroachment_from_s_m,
        p.actor_occupancy_hi_m - $encroachment_end_buffer * (p.actor_occupancy_hi_m - p.actor_occupancy_lo_m)
            as actor_encroachment_to_s_m,
        p.actor_kind_ok,
        p.actor_from_other_entry
    from pairs as p
    inner join ego_measured as e
        on p.drive_key = e.drive_key and p.ego_key = e.ego_key and p.ego_passage = e.ego_passage
    left join junction_frames as a
        on p.drive_key = a.drive_key and p.actor_key = a.actor_key and p.actor_passage = a.passage
        and e.frame = a.frame
),

conditions as (
    select
        *,
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
        coalesce(actor_first and frame < ego_encroachment_frame, false) as ego_yields,
        coalesce(actor_s_m between actor_encroachment_from_s_m and actor_encroachment_to_s_m, false)
            as actor_in_encroachment,
        coalesce(actor_s_m >= actor_encroachment_from_s_m
            and actor_offset_from_junction_end_m <= $max_offset_from_junction_end_m, false) as actor_crossing,
        coalesce(ego_offset_from_junction_start_m >= $min_offset_from_junction_start_m
            and ego_offset_from_junction_end_m <= 0, false) as ego_in_junction
    from measured
),

pair_stops as (
    -- per pair of passages: the actor's first frame at min_offset_from_junction_end from the junction end, and
    -- the ego's last stand before its box reaches the encroachment area (before it leaves the junction when the
    -- paths share no area): it sets off on its turn at the next frame
    select
        drive_key,
        ego_key,
        ego_passage,
        actor_key,
        actor_passage,
        min(case when actor_offset_from_junction_end_m >= $min_offset_from_junction_end_m then frame end)
            as actor_end_frame,
        max(case when ego_stopped and (ego_encroachment_frame is null or frame < ego_encroachment_frame)
                 then frame end) as ego_last_stop_frame
    from conditions
    group by drive_key, ego_key, ego_passage, actor_key, actor_passage
),

pair_candidates as (
    -- the actors the ego may have waited for: of kinds, from another entry, crossing its path first, and on that
    -- path (the box reached the area) by the time the ego sets off from its last stand before it
    select
        s.*,
        p.actor_out_frame as actor_clear_frame,
        p.actor_kind_ok and p.actor_from_other_entry and coalesce(p.actor_first, false)
            and coalesce(p.actor_in_frame <= s.ego_last_stop_frame + 1, false) as waited_candidate
    from pair_stops as s
    inner join pairs as p
        on s.drive_key = p.drive_key and s.ego_key = p.ego_key and s.ego_passage = p.ego_passage
        and s.actor_key = p.actor_key and s.actor_passage = p.actor_passage
),

clearing as (
    -- over every actor of the ego's passage, the frame at which the last candidate leaves the ego's path: the
    -- actor the ego waited for, with any that left it at most max_gap earlier (two oncoming lanes passing
    -- together). Reached, not left, by the set-off: a driver sets off as the car it waited for is clearing its
    -- path, so "left before the set-off" turned on a frame or two and credited the car before it. And the
    -- ego's last stand before the turn: its latest stand before a candidate's area, so that an ego that rolls
    -- into the junction behind one car and stands there for the oncoming ones sets off on its turn once
    select
        c.drive_key,
        c.ego_key,
        c.ego_passage,
        max(case when c.waited_candidate then c.actor_clear_frame end)
            - floor($max_gap_s / nullif(max(d.dt_s), 0) + 1e-9) as waited_for_from_frame,
        max(case when c.waited_candidate then c.ego_last_stop_frame end) as ego_turn_stop_frame
    from pair_candidates as c
    inner join drive_inputs as d
        on c.drive_key = d.drive_key
    group by c.drive_key, c.ego_key, c.ego_passage
),

waiting as (
    -- phase 1's conditions but the stop itself
    select
        *,
        actor_kind_ok and ego_turns_left and ego_near_junction_start and light_in_range and light_green
            and actor_approaching and ego_yields as ego_waiting
    from conditions
),

waiting_pairs as (
    -- the pairs with a frame of waiting: at the others' frames the last frame at which the ego was not waiting
    -- is the frame itself, and the ego never stopped waiting
    select distinct drive_key, ego_key, ego_passage, actor_key, actor_passage
    from waiting
    where ego_waiting
),

stretches as (
    -- per frame of those pairs, the last frame (so far) at which the ego was not waiting, and the last (so far)
    -- at which it was waiting and stopped
    select
        w.drive_key,
        w.ego_key,
        w.ego_passage,
        w.actor_key,
        w.actor_passage,
        w.frame,
        max(case when not w.ego_waiting then w.frame end) over (
            partition by w.drive_key, w.ego_key, w.ego_passage, w.actor_key, w.actor_passage order by w.frame
            rows between unbounded preceding and current row
        ) as waiting_since_frame,
        max(case when w.ego_waiting and w.ego_stopped then w.frame end) over (
            partition by w.drive_key, w.ego_key, w.ego_passage, w.actor_key, w.actor_passage order by w.frame
            rows between unbounded preceding and current row
        ) as last_waiting_stop_frame
    from waiting as w
    inner join waiting_pairs as p
        on w.drive_key = p.drive_key and w.ego_key = p.ego_key and w.ego_passage = p.ego_passage
        and w.actor_key = p.actor_key and w.actor_passage = p.actor_passage
)

select
    w.drive_id,
    w.ego_id,
    w.actor_id,
    w.drive_key,
    w.ego_key,
    w.actor_key,
    w.actor_kind,
    w.frame,
    w.t_s,
    w.ego_passage,
    w.actor_passage,
    w.junction_id,
    w.ego_s_m,
    w.actor_s_m,
    w.ego_offset_from_junction_start_m,
    w.ego_offset_from_junction_end_m,
    w.actor_offset_from_junction_start_m,
    w.actor_offset_from_junction_end_m,
    w.ego_speed_mps,
    w.ego_turn,
    w.light_state,
    w.actor_entry_leg,
    w.actor_exit_leg,
    w.traversal_relative_direction,
    w.encroachment_area_m2,
    w.actor_first,
    w.pet_s,
    w.ego_encroachment_frame,
    w.actor_reach_frame,
    w.actor_clear_frame,
    s.actor_end_frame,
    w.actor_encroachment_from_s_m,
    w.actor_encroachment_to_s_m,
    w.actor_kind_ok,
    w.ego_turns_left,
    w.ego_near_junction_start,
    w.ego_stopped,
    w.light_in_range,
    w.light_green,
    w.actor_approaching,
    w.actor_inside_junction,
    w.actor_from_other_entry,
    w.ego_yields,
    w.actor_in_encroachment,
    w.actor_crossing,
    coalesce(s.actor_end_frame < w.ego_encroachment_frame, false) as actor_reaches_junction_end,
    w.ego_in_junction,
    w.ego_waiting,
    case when p.frame is null then w.frame else p.waiting_since_frame end as waiting_since_frame,
    s.ego_last_stop_frame,
    s.waited_candidate,
    c.waited_for_from_frame,
    c.ego_turn_stop_frame,
    -- the ego stopped at some frame of the current stretch of waiting (the stop starts phase 1; it then gives
    -- the right of way, pulling forward to its waiting position or not)
    coalesce(p.last_waiting_stop_frame > coalesce(p.waiting_since_frame, -1), false) as ego_has_stopped,
    w.ego_in_junction and coalesce(w.frame > coalesce(c.ego_turn_stop_frame, s.ego_last_stop_frame), true)
        as ego_turning,
    -- crossing, or, for the last actor the ego waited for, past the encroachment area until the ego sets off
    w.actor_crossing or coalesce(w.actor_clear_frame >= c.waited_for_from_frame
                                 and w.actor_clear_frame <= c.ego_turn_stop_frame + 1
                                 and w.frame >= w.actor_clear_frame
                                 and w.frame <= c.ego_turn_stop_frame, false) as actor_finishing
from waiting as w
inner join pair_candidates as s
    on w.drive_key = s.drive_key and w.ego_key = s.ego_key and w.ego_passage = s.ego_passage
    and w.actor_key = s.actor_key and w.actor_passage = s.actor_passage
inner join clearing as c
    on w.drive_key = c.drive_key and w.ego_key = c.ego_key and w.ego_passage = c.ego_passage
left join stretches as p
    on w.drive_key = p.drive_key and w.ego_key = p.ego_key and w.ego_passage = p.ego_passage
    and w.actor_key = p.actor_key and w.actor_passage = p.actor_passage and w.frame = p.frame
