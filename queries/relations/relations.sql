-- relations: relations
-- grain: one row per (drive_id, ego_id, actor_id, frame) for every actor of the run's relation kinds within
--        relation_range of an ego
-- reads: tracks, ego_lanes, actor_lanes, track_lanes, drive_inputs, lane_neighbours, lane_line
-- params: $relation_range_m, $object_relation_range_m, $min_closing_speed_mps, $relation_kinds_csv
--
-- Joined on the integer keys ingest assigns (schema.TRACK_KEYS), which each row carries beside the ids:
--   drive_key, ego_key, actor_key   integer keys of the drive, the ego and the actor (tracks.drive_key, actor_key)
--
-- Pairs are kept while the centres are at most relation_range apart for vehicle kinds, and at most
-- object_relation_range apart for every other kind (people, cyclists, cones): close-object scenarios look
-- within metres, lane-following ones up to a 5 s headway.
--
-- Only actors whose kind is in relation_kinds_csv (',cyclist,') are related: the kinds some scenario of the run
-- can use (each scenario's `relation_kinds`, every kind when one leaves it unset; logiq_sql.spec.plan.relation_kinds_csv).
-- A run of cyclist_close_to_moving_sut alone relates cyclists only; a run with any lane-following or junction
-- scenario relates every kind (the nearest road user ahead or behind may be of any kind), so its rows are the full
-- relation. relations_of(drive_id, ego_id) gives every kind, whatever a run kept (docs/semantics.md).
--
-- Geometry in the ego frame (x forward along the ego heading, y to the ego's left), boxes from
-- length_m/width_m around the centre:
--   dx_m, dy_m          actor centre in the ego frame
--   lon_gap_m           bumper-to-bumper gap along the ego x axis: |dx| - L_ego/2 - (actor half extent on x),
--                       0 when the projections overlap
--   lat_gap_m           side-to-side gap along the ego y axis, same rule
--   box_distance_m      closest distance between the two boxes, 0 when they overlap (separating-axis test);
--                       otherwise the least corner-to-box distance over the 8 corners (exact for rectangles)
--   ego_lane_id         the ego's lane (ego_lanes.lane_id), lane_run its lane run (ego_lanes.lane_run)
--   ego_speed_mps, actor_speed_mps  the two speeds (tracks.speed_mps): the phases read them from here, not
--                       from tracks
--   same_lane           the actor's lane is the ego's lane, or a lane that continues it (lane_line), or one of the
--                       two centres lies inside the other's lane (where lanes overlap, at a fork)
--   adjacent_side       'left'/'right' when the actor's lane is beside the ego's lane (lane_neighbours) and the
--                       two are not in the same lane
--   closing_speed_mps   rate at which lon_gap shrinks: actor speed along the ego axis minus ego speed,
--                       sign taken so that positive means closing
--   time_headway_s      lon_gap / speed of the trailing vehicle (the one behind); NULL if it does not move
--                       forward
--   ttc_s               lon_gap / closing speed, for actors whose box overlaps the ego's laterally
--                       (lat_gap = 0); 0 when the boxes overlap; NULL when not overlapping or not closing: a
--                       closing speed of at most min_closing_speed (0.1 m/s by default) is not closing (a
--                       pair closing at 1e-16 m/s would otherwise get a TTC of 1e16 s)
--   mttc_s              Ozbay et al. (2008) MTTC with constant relative acceleration: the least positive root
--                       of 0.5*a*t^2 + v*t - lon_gap = 0 (v closing speed, a closing acceleration); D/v when
--                       |a| < 1e-6 and v > min_closing_speed; NULL when no positive root, when |a| < 1e-6 and
--                       v <= min_closing_speed, or not laterally overlapping; 0 on overlap
with

ego as (
    -- each ego row three times, once per band of x it may meet actors in: bands are as wide as the larger range
    -- (relation_range, object_relation_range) plus 1 m, so every actor within range is in the ego's band or the
    -- next one on either side, and the pair join below is an equi-join on (drive, frame, band) instead of on
    -- (drive, frame) alone, which paired every ego row with every actor of its frame before the range test (a
    -- cheaper join: benchmarks/README.md). The range test is the same, so the pairs are the same; the
    -- extra metre keeps a pair at exactly the range in a neighbouring band whatever the rounding of the divisions
    select
        t.*,
        el.lane_id as ego_lane_id,
        el.lane_run,
        cast(floor(t.x_m / (greatest($relation_range_m, $object_relation_range_m) + 1.0)) as bigint) + n.d as band
    from tracks as t
    inner join ego_lanes as el
        on t.drive_key = el.drive_key and t.actor_key = el.ego_key and t.frame = el.frame
    cross join (select -1 as d union all select 0 as d union all select 1 as d) as n
),

pairs as (
    select
        e.drive_key,
        e.actor_key as ego_key,
        a.actor_key,
        e.drive_id,
        e.actor_id as ego_id,
        a.actor_id,
        a.kind as actor_kind,
        e.frame,
        e.t_s,
        e.ego_lane_id,
        e.lane_run,
        e.speed_mps as ego_speed_mps,
        e.accel_mps2 as ego_accel_mps2,
        e.length_m as ego_length_m,
        e.width_m as ego_width_m,
        a.speed_mps as actor_speed_mps,
        a.accel_mps2 as actor_accel_mps2,
        a.length_m as actor_length_m,
        a.width_m as actor_width_m,
        (a.x_m - e.x_m) * cos(e.heading_rad) + (a.y_m - e.y_m) * sin(e.heading_rad) as dx_m,
        (a.y_m - e.y_m) * cos(e.heading_rad) - (a.x_m - e.x_m) * sin(e.heading_rad) as dy_m,
        atan2(sin(a.heading_rad - e.heading_rad), cos(a.heading_rad - e.heading_rad)) as rel_heading_rad
    from ego as e
    inner join (
        select
            *,
            case
                when kind in ('vehicle', 'truck', 'bus', 'trailer', 'motorcycle', 'emergency_vehicle')
                    then $relation_range_m * $relation_range_m
                else $object_relation_range_m * $object_relation_range_m
            end as range_sq_m2,
            cast(floor(x_m / (greatest($relation_range_m, $object_relation_range_m) + 1.0)) as bigint) as band
        from tracks
        where instr($relation_kinds_csv, ',' || kind || ',') > 0
    ) as a
        on e.drive_key = a.drive_key
        and e.frame = a.frame
        and e.band = a.band
        and e.actor_key <> a.actor_key
        and (a.x_m - e.x_m) * (a.x_m - e.x_m) + (a.y_m - e.y_m) * (a.y_m - e.y_m) <= a.range_sq_m2
),

rotated as (
    select
        *,
        cos(rel_heading_rad) as c,
        sin(rel_heading_rad) as s,
        -(dx_m * cos(rel_heading_rad) + dy_m * sin(rel_heading_rad)) as ego_u_m,
        dx_m * sin(rel_heading_rad) - dy_m * cos(rel_heading_rad) as ego_v_m
    from pairs
),

gaps as (
    select
        *,
        abs(dx_m) - ego_length_m / 2 - abs(actor_length_m / 2 * c) - abs(actor_width_m / 2 * s) as lon_gap_raw_m,
        abs(dy_m) - ego_width_m / 2 - abs(actor_length_m / 2 * s) - abs(actor_width_m / 2 * c) as lat_gap_raw_m,
        abs(ego_u_m) - actor_length_m / 2 - abs(ego_length_m / 2 * c) - abs(ego_width_m / 2 * s) as u_gap_raw_m,
        abs(ego_v_m) - actor_width_m / 2 - abs(ego_length_m / 2 * s) - abs(ego_width_m / 2 * c) as v_gap_raw_m,
        -- actor corners in the ego frame (p, q = +-1 along the actor's length and width)
        dx_m + actor_length_m / 2 * c - actor_width_m / 2 * s as a1x,
        dy_m + actor_length_m / 2 * s + actor_width_m / 2 * c as a1y,
        dx_m + actor_length_m / 2 * c + actor_width_m / 2 * s as a2x,
        dy_m + actor_length_m / 2 * s - actor_width_m / 2 * c as a2y,
        dx_m - actor_length_m / 2 * c - actor_width_m / 2 * s as a3x,
        dy_m - actor_length_m / 2 * s + actor_width_m / 2 * c as a3y,
        dx_m - actor_length_m / 2 * c + actor_width_m / 2 * s as a4x,
        dy_m - actor_length_m / 2 * s - actor_width_m / 2 * c as a4y,
        -- ego corners in the actor frame
        ego_u_m + ego_length_m / 2 * c + ego_width_m / 2 * s as e1u,
        ego_v_m - ego_length_m / 2 * s + ego_width_m / 2 * c as e1v,
        ego_u_m + ego_length_m / 2 * c - ego_width_m / 2 * s as e2u,
        ego_v_m - ego_length_m / 2 * s - ego_width_m / 2 * c as e2v,
        ego_u_m - ego_length_m / 2 * c + ego_width_m / 2 * s as e3u,
        ego_v_m + ego_length_m / 2 * s + ego_width_m / 2 * c as e3v,
        ego_u_m - ego_length_m / 2 * c - ego_width_m / 2 * s as e4u,
        ego_v_m + ego_length_m / 2 * s - ego_width_m / 2 * c as e4v
    from rotated
),

corner_offsets as (
    -- how far each corner lies outside the other box, along that box's length and width
    select
        *,
        greatest(abs(a1x) - ego_length_m / 2, 0) as a1_out_x,
        greatest(abs(a1y) - ego_width_m / 2, 0) as a1_out_y,
        greatest(abs(a2x) - ego_length_m / 2, 0) as a2_out_x,
        greatest(abs(a2y) - ego_width_m / 2, 0) as a2_out_y,
        greatest(abs(a3x) - ego_length_m / 2, 0) as a3_out_x,
        greatest(abs(a3y) - ego_width_m / 2, 0) as a3_out_y,
        greatest(abs(a4x) - ego_length_m / 2, 0) as a4_out_x,
        greatest(abs(a4y) - ego_width_m / 2, 0) as a4_out_y,
        greatest(abs(e1u) - actor_length_m / 2, 0) as e1_out_x,
        greatest(abs(e1v) - actor_width_m / 2, 0) as e1_out_y,
        greatest(abs(e2u) - actor_length_m / 2, 0) as e2_out_x,
        greatest(abs(e2v) - actor_width_m / 2, 0) as e2_out_y,
        greatest(abs(e3u) - actor_length_m / 2, 0) as e3_out_x,
        greatest(abs(e3v) - actor_width_m / 2, 0) as e3_out_y,
        greatest(abs(e4u) - actor_length_m / 2, 0) as e4_out_x,
        greatest(abs(e4v) - actor_width_m / 2, 0) as e4_out_y
    from gaps
),

measured as (
    select
        *,
        lon_gap_raw_m <= 0 and lat_gap_raw_m <= 0 and u_gap_raw_m <= 0 and v_gap_raw_m <= 0 as boxes_overlap,
        greatest(lon_gap_raw_m, 0) as lon_gap_m,
        greatest(lat_gap_raw_m, 0) as lat_gap_m,
        sqrt(least(
            a1_out_x * a1_out_x + a1_out_y * a1_out_y,
            a2_out_x * a2_out_x + a2_out_y * a2_out_y,
            a3_out_x * a3_out_x + a3_out_y * a3_out_y,
            a4_out_x * a4_out_x + a4_out_y * a4_out_y,
            e1_out_x * e1_out_x + e1_out_y * e1_out_y,
            e2_out_x * e2_out_x + e2_out_y * e2_out_y,
            e3_out_x * e3_out_x + e3_out_y * e3_out_y,
            e4_out_x * e4_out_x + e4_out_y * e4_out_y
        )) as corner_distance_m,
        case
            when dx_m >= 0 then ego_speed_mps - actor_speed_mps * c
            else actor_speed_mps * c - ego_speed_mps
        end as closing_speed_mps,
        case
            when dx_m >= 0 then ego_accel_mps2 - actor_accel_mps2 * c
            else actor_accel_mps2 * c - ego_accel_mps2
        end as closing_accel_mps2
    from corner_offsets
),

lane_pairs as (
    select
        m.*,
        al.lane_id as actor_lane_id,
        line.lane_id is not null
            -- where two lanes overlap (a lane that forks, or widens into two), a centre inside both is in either:
            -- the actor inside the ego's lane, or the ego inside the actor's, is in the same lane (headed its way,
            -- as actor_lanes asks)
            or actor_inside.lane_id is not null or ego_inside.lane_id is not null as same_lane,
        beside.side as beside_side
    from measured as m
    inner join drive_inputs as d
        on m.drive_key = d.drive_key
    left join actor_lanes as al
        on m.drive_key = al.drive_key and m.actor_key = al.actor_key and m.frame = al.frame
    left join lane_neighbours as beside
        on d.map_id = beside.map_id and m.ego_lane_id = beside.lane_id and al.lane_id = beside.near_lane_id
    left join lane_line as line
        on d.map_id = line.map_id and m.ego_lane_id = line.lane_id and al.lane_id = line.line_lane_id
    left join track_lanes as actor_inside
        on m.drive_key = actor_inside.drive_key and m.actor_key = actor_inside.actor_key
        and m.frame = actor_inside.frame and m.ego_lane_id = actor_inside.lane_id and actor_inside.dist_m = 0
        and abs(actor_inside.heading_diff_rad) < pi() / 2
    left join track_lanes as ego_inside
        on m.drive_key = ego_inside.drive_key and m.ego_key = ego_inside.actor_key
        and m.frame = ego_inside.frame and al.lane_id = ego_inside.lane_id and ego_inside.dist_m = 0
        and abs(ego_inside.heading_diff_rad) < pi() / 2
),

lane_relation as (
    select
        *,
        case when not same_lane then beside_side end as adjacent_side
    from lane_pairs
),

mttc_roots as (
    select
        *,
        closing_speed_mps * closing_speed_mps + 2 * closing_accel_mps2 * lon_gap_m as discriminant,
        (-closing_speed_mps + sqrt(greatest(closing_speed_mps * closing_speed_mps + 2 * closing_accel_mps2 * lon_gap_m, 0)))
            / nullif(closing_accel_mps2, 0) as root_plus_s,
        (-closing_speed_mps - sqrt(greatest(closing_speed_mps * closing_speed_mps + 2 * closing_accel_mps2 * lon_gap_m, 0)))
            / nullif(closing_accel_mps2, 0) as root_minus_s
    from lane_relation
)

select
    drive_id,
    ego_id,
    actor_id,
    actor_kind,
    frame,
    t_s,
    dx_m,
    dy_m,
    rel_heading_rad,
    lon_gap_m,
    lat_gap_m,
    case when boxes_overlap then 0.0 else corner_distance_m end as box_distance_m,
    ego_lane_id,
    lane_run,
    actor_lane_id,
    same_lane,
    adjacent_side,
    case when dy_m >= 0 then 'left' else 'right' end as side,
    closing_speed_mps,
    ego_speed_mps,
    actor_speed_mps,
    case
        when dx_m < 0 and actor_speed_mps > 0 then lon_gap_m / actor_speed_mps
        when dx_m >= 0 and ego_speed_mps > 0 then lon_gap_m / ego_speed_mps
    end as time_headway_s,
    case
        when boxes_overlap then 0.0
        when lat_gap_m > 0 then null
        when closing_speed_mps > $min_closing_speed_mps then lon_gap_m / closing_speed_mps
    end as ttc_s,
    case
        when boxes_overlap then 0.0
        when lat_gap_m > 0 then null
        when closing_accel_mps2 is null or abs(closing_accel_mps2) < 1e-6 then
            case when closing_speed_mps > $min_closing_speed_mps then lon_gap_m / closing_speed_mps end
        when discriminant < 0 then null
        when root_plus_s > 0 and root_minus_s > 0 then least(root_plus_s, root_minus_s)
        when root_plus_s > 0 then root_plus_s
        when root_minus_s > 0 then root_minus_s
    end as mttc_s,
    drive_key,
    ego_key,
    actor_key
from mttc_roots
