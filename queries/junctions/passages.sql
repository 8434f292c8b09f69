-- junctions: passages
-- grain: one row per (drive_id, actor_id, passage): one stay of an actor inside one junction
-- reads: actor_paths, track_lanes, actor_lanes, lanes, lane_successors, drive_inputs
-- params: none
--
-- Path positions s_m come from actor_paths. Joined, windowed and grouped on the integer keys (drive_key, actor_key),
-- which each row carries beside the ids.
--   inside            the centre lies in a lane of the junction (track_lanes distance 0); of two junctions
--                     whose lanes overlap there, the smaller id
--   passage           consecutive inside frames of one junction; a new stay that starts less than 2 m of path
--                     after the last one ended is the same passage (a stopped car on the junction boundary)
--   entry_* / exit_*  the first and last frame inside; entry_s_m / exit_s_m, where the path crosses the junction
--                     boundary, are taken halfway between the samples on either side of it
--   entry_observed    the actor was seen outside the junction before it entered (else offsets from the start
--                     and the entry leg are unknown); exit_observed likewise after it left
--   entry_lane_id     the actor's lane at the last frame before entry that has one outside this junction
--   exit_lane_id      its lane at the first such frame after exit
--   entry_heading_rad heading at the last frame seen before entry (the inbound direction; a dropped frame just
--                     before it does not leave it unknown); exit_heading_rad at the first frame seen after exit
--                     (the outbound direction)
--   turn_from_map     the turn the map gives the connection from entry_lane_id to the junction lane that
--                     leads on (directly or through one more junction lane) to exit_lane_id; NULL when the
--                     map has no turn for it or gives two different ones
--   turn_from_heading from the heading change d = exit_heading - entry_heading wrapped into (-180, 180]
--                     degrees: |d| <= 30 straight, 30 < d < 150 left, -150 < d < -30 right, |d| >= 150 u_turn
--   turn              turn_from_map where the map has it, else turn_from_heading; NULL when neither is known
with

inside as (
    select
        tl.drive_key,
        tl.actor_key,
        tl.frame,
        min(l.junction_id) as junction_id
    from track_lanes as tl
    inner join (select distinct drive_key, actor_key from actor_paths) as a
        on tl.drive_key = a.drive_key and tl.actor_key = a.actor_key
    inner join drive_inputs as d
        on tl.drive_key = d.drive_key
    inner join lanes as l
        on d.map_id = l.map_id and tl.lane_id = l.lane_id
    where tl.dist_m = 0 and l.junction_id is not null
    group by tl.drive_key, tl.actor_key, tl.frame
),

path as (
    -- the rows of the actors that are ever inside a junction: the windows run over each actor's rows alone, so
    -- leaving out the others changes no row of theirs
    select
        p.*,
        (coalesce(lag(p.s_m) over w, p.s_m) + p.s_m) / 2 as boundary_before_m,
        (p.s_m + coalesce(lead(p.s_m) over w, p.s_m)) / 2 as boundary_after_m,
        lag(p.heading_rad) over w as heading_before_rad,
        lead(p.heading_rad) over w as heading_after_rad
    from actor_paths as p
    inner join (select distinct drive_key, actor_key from inside) as i
        on p.drive_key = i.drive_key and p.actor_key = i.actor_key
    window w as (partition by p.drive_key, p.actor_key order by p.frame)
),

stays as (
    -- islands of consecutive inside frames in one junction
    select
        p.*,
        i.junction_id,
        p.frame - row_number() over (partition by p.drive_key, p.actor_key, i.junction_id order by p.frame) as island
    from path as p
    inner join inside as i
        on p.drive_key = i.drive_key and p.actor_key = i.actor_key and p.frame = i.frame
),

stay_bounds as (
    select
        drive_key,
        actor_key,
        min(drive_id) as drive_id,
        min(actor_id) as actor_id,
        junction_id,
        min(frame) as entry_frame,
        max(frame) as exit_frame,
        min(boundary_before_m) as entry_s_m,
        max(boundary_after_m) as exit_s_m,
        min(first_frame) as first_frame,
        min(last_frame) as last_frame
    from stays
    group by drive_key, actor_key, junction_id, island
),

merged as (
    select
        *,
        -- bigint on every engine (DuckDB sums integers into a 128-bit integer, Spark into bigint)
        cast(sum(starts_new) over (
            partition by drive_key, actor_key order by entry_frame rows between unbounded preceding and current row
        ) as bigint) as passage
    from (
        select
            *,
            case
                when junction_id = lag(junction_id) over w and entry_s_m - lag(exit_s_m) over w < 2.0 then 0
                else 1
            end as starts_new
        from stay_bounds
        window w as (partition by drive_key, actor_key order by entry_frame)
    ) as flagged
),

passages as (
    select
        drive_key,
        actor_key,
        min(drive_id) as drive_id,
        min(actor_id) as actor_id,
        passage,
        min(junction_id) as junction_id,
        min(entry_frame) as entry_frame,
        max(exit_frame) as exit_frame,
        min(entry_s_m) as entry_s_m,
        max(exit_s_m) as exit_s_m,
        min(entry_frame) > min(first_frame) as entry_observed,
        max(exit_frame) < min(last_frame) as exit_observed
    from merged
    group by drive_key, actor_key, passage
),

outside_lanes as (
    -- frames near a passage at which the actor is in a lane that is not in that junction
    select
        p.drive_key,
        p.actor_key,
        p.passage,
        al.frame,
        al.lane_id,
        al.frame < p.entry_frame as before
    from passages as p
    inner join actor_lanes as al
        on p.drive_key = al.drive_key and p.actor_key = al.actor_key
        and (al.frame between p.entry_frame - 50 and p.entry_frame - 1
            or al.frame between p.exit_frame + 1 and p.exit_frame + 50)
    inner join drive_inputs as d
        on p.drive_key = d.drive_key
    inner join lanes as l
        on d.map_id = l.map_id and al.lane_id = l.lane_id
    where l.junction_id is null or l.junction_id <> p.junction_id
),

legs as (
    select
        drive_key,
        actor_key,
        passage,
        max(case when before then frame end) as entry_lane_frame,
        min(case when not before then frame end) as exit_lane_frame
    from outside_lanes
    group by drive_key, actor_key, passage
),

with_legs as (
    select
        p.*,
        d.map_id,
        el.lane_id as entry_lane_id,
        xl.lane_id as exit_lane_id,
        eh.heading_before_rad as entry_heading_rad,
        xh.heading_after_rad as exit_heading_rad
    from passages as p
    inner join drive_inputs as d
        on p.drive_key = d.drive_key
    left join legs as g
        on p.drive_key = g.drive_key and p.actor_key = g.actor_key and p.passage = g.passage
    left join outside_lanes as el
        on p.drive_key = el.drive_key and p.actor_key = el.actor_key and p.passage = el.passage
        and el.frame = g.entry_lane_frame
    left join outside_lanes as xl
        on p.drive_key = xl.drive_key and p.actor_key = xl.actor_key and p.passage = xl.passage
        and xl.frame = g.exit_lane_frame
    left join path as eh
        on p.drive_key = eh.drive_key and p.actor_key = eh.actor_key and eh.frame = p.entry_frame
    left join path as xh
        on p.drive_key = xh.drive_key and p.actor_key = xh.actor_key and xh.frame = p.exit_frame
),

map_turns as (
    -- entry lane -> junction lane (the map's turn) -> [one more junction lane ->] exit lane
    select
        w.drive_key,
        w.actor_key,
        w.passage,
        case when min(first_hop.turn) = max(first_hop.turn) then min(first_hop.turn) end as turn_from_map
    from with_legs as w
    inner join lane_successors as first_hop
        on w.map_id = first_hop.map_id and w.entry_lane_id = first_hop.lane_id
    left join lane_successors as second_hop
        on first_hop.map_id = second_hop.map_id and first_hop.successor_id = second_hop.lane_id
    left join lane_successors as third_hop
        on second_hop.map_id = third_hop.map_id and second_hop.successor_id = third_hop.lane_id
    where first_hop.turn is not null
        and (second_hop.successor_id = w.exit_lane_id or third_hop.successor_id = w.exit_lane_id)
    group by w.drive_key, w.actor_key, w.passage
),

turns as (
    select
        w.*,
        m.turn_from_map,
        case
            when w.entry_heading_rad is null or w.exit_heading_rad is null then null
            when abs(degrees(atan2(sin(w.exit_heading_rad - w.entry_heading_rad),
                                   cos(w.exit_heading_rad - w.entry_heading_rad)))) <= 30 then 'straight'
            when abs(degrees(atan2(sin(w.exit_heading_rad - w.entry_heading_rad),
                                   cos(w.exit_heading_rad - w.entry_heading_rad)))) >= 150 then 'u_turn'
            when atan2(sin(w.exit_heading_rad - w.entry_heading_rad),
                       cos(w.exit_heading_rad - w.entry_heading_rad)) > 0 then 'left'
            else 'right'
        end as turn_from_heading
    from with_legs as w
    left join map_turns as m
        on w.drive_key = m.drive_key and w.actor_key = m.actor_key and w.passage = m.passage
)

select
    drive_id,
    actor_id,
    passage,
    map_id,
    junction_id,
    entry_frame,
    exit_frame,
    entry_s_m,
    exit_s_m,
    entry_observed,
    exit_observed,
    entry_lane_id,
    exit_lane_id,
    entry_heading_rad,
    exit_heading_rad,
    turn_from_map,
    turn_from_heading,
    coalesce(turn_from_map, turn_from_heading) as turn,
    drive_key,
    actor_key
from turns
