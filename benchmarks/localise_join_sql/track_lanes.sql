-- benchmark, not wired in: track_lanes (map localisation) as a join; ingest uses logiq_sql/ingestion/localise.py
-- grain: one row per (drive_id, actor_id, frame, lane_id) with the box centre within $range_m of the lane polygon
-- reads: tracks (staged), _drive_maps (drive_id, map_no: the drives to localise and their maps), lane_grid
--        (benchmarks.localise_join.lane_grid: the map's lane pieces by cell), lane_names (lane_no, lane_id)
-- params: $cells_per_m (1 / the grid's cell size, a power of two), $range_m (schema.LOCALISATION_RANGE_M)
--
-- DuckDB only as written: "as not materialized" keeps DuckDB from materialising the CTEs that the union
-- reads twice (3.3 -> 1.6-2.0 CPU s on the largest base map); without it the text is the portable subset.
--
-- Every moving row joins the rows of its cell (an equi-join on the cell): per lane near the cell, n_rows rows,
-- the k-th holding the lane's k-th boundary edge and k-th centre-line segment that a point of the cell may need
-- (either may be absent). Per (row, lane), grouped only where n_rows > 1:
--   inside            the cell's reference point q is inside the polygon, and an even number of boundary edges
--                     cross the segment from the row's point to q (or q is outside and the number is odd); a
--                     vertex on the line through the point and q counts as left of it
--   dist_m            0 inside, else the least distance to a boundary edge (GEOS's point-to-segment formula);
--                     kept when inside or within $range_m
--   heading_diff_rad  heading minus the direction of the centre line at line_locate_point of the point: the
--                     nearest segment (the first one on a tie) gives the arc length (GEOS's formula), and the
--                     segment whose arc-length keys hold it gives the direction (LaneIndex's keys)
with

points as not materialized (
    select
        t.drive_id,
        t.actor_id,
        t.frame,
        t.x_m,
        t.y_m,
        t.heading_rad,
        m.map_no,
        cast(floor(t.x_m * $cells_per_m) as bigint) as cell_x,
        cast(floor(t.y_m * $cells_per_m) as bigint) as cell_y
    from tracks as t
    inner join _drive_maps as m on m.drive_id = t.drive_id
    where t.kind not in ('object', 'fod', 'sign')
),

joined as not materialized (
    select
        p.drive_id,
        p.actor_id,
        p.frame,
        p.heading_rad,
        p.x_m,
        p.y_m,
        g.*,
        case when g.e_len2 > 0 then ((p.x_m - g.e_a_x) * g.e_dx + (p.y_m - g.e_a_y) * g.e_dy) / g.e_len2 end as e_r,
        case when g.c_len2 > 0 then ((p.x_m - g.c_a_x) * g.c_dx + (p.y_m - g.c_a_y) * g.c_dy) / g.c_len2 end as c_r
    from points as p
    inner join lane_grid as g on g.map_no = p.map_no and g.cell_x = p.cell_x and g.cell_y = p.cell_y
),

measured as not materialized (
    select
        drive_id,
        actor_id,
        frame,
        heading_rad,
        lane_no,
        n_rows,
        q_inside,
        c_seg_no,
        -- distance to the edge, GEOS's Distance::pointToSegment
        case
            when e_a_x is null then null
            when e_r is null or e_r <= 0 then sqrt((x_m - e_a_x) * (x_m - e_a_x) + (y_m - e_a_y) * (y_m - e_a_y))
            when e_r >= 1 then sqrt((x_m - e_b_x) * (x_m - e_b_x) + (y_m - e_b_y) * (y_m - e_b_y))
            else abs(case when e_len2 > 0 then ((e_a_y - y_m) * e_dx - (e_a_x - x_m) * e_dy) / e_len2 end) * e_len
        end as e_dist,
        -- 1 when the edge crosses the segment from the point to q
        case
            when e_a_x is null then 0
            when ((qx - x_m) * (e_a_y - y_m) - (qy - y_m) * (e_a_x - x_m) >= 0)
                = ((qx - x_m) * (e_b_y - y_m) - (qy - y_m) * (e_b_x - x_m) >= 0) then 0
            when e_q_side > 0 and e_dx * (y_m - e_a_y) - e_dy * (x_m - e_a_x) < 0 then 1
            when e_q_side < 0 and e_dx * (y_m - e_a_y) - e_dy * (x_m - e_a_x) > 0 then 1
            else 0
        end as crosses,
        case
            when c_a_x is null then null
            when c_r is null or c_r <= 0 then sqrt((x_m - c_a_x) * (x_m - c_a_x) + (y_m - c_a_y) * (y_m - c_a_y))
            when c_r >= 1 then sqrt((x_m - c_b_x) * (x_m - c_b_x) + (y_m - c_b_y) * (y_m - c_b_y))
            else abs(case when c_len2 > 0 then ((c_a_y - y_m) * c_dx - (c_a_x - x_m) * c_dy) / c_len2 end)
                * c_seg_len
        end as c_dist,
        -- the arc length of line_locate_point on this segment (GEOS's LengthIndexOfPoint), shifted by the lane
        case
            when c_r is null or c_r <= 0 then c_start_m
            when c_r <= 1 then c_start_m + c_r * c_seg_len
            else c_start_m + c_seg_len
        end + c_shift as t,
        c_key_lo,
        c_key_hi,
        c_dir_before,
        c_dir_mid,
        c_dir_after
    from joined
),

headed as not materialized (
    select
        *,
        case when t < c_key_lo then c_dir_before when t >= c_key_hi then c_dir_after else c_dir_mid end
            as lane_heading
    from measured
),

per_lane as not materialized (
    select
        drive_id,
        actor_id,
        frame,
        heading_rad,
        lane_no,
        (q_inside + crosses) % 2 = 1 as inside,
        e_dist as edge_dist,
        lane_heading
    from headed
    where n_rows = 1
    union all
    select
        drive_id,
        actor_id,
        frame,
        heading_rad,
        lane_no,
        (max(q_inside) + sum(crosses)) % 2 = 1 as inside,
        min(e_dist) as edge_dist,
        -- the nearest segment; on a tie the first one, as GEOS
        arg_min(lane_heading, case when c_dist is not null then struct_pack(d := c_dist, seg_no := c_seg_no) end)
            as lane_heading
    from headed
    where n_rows > 1
    group by drive_id, actor_id, frame, heading_rad, lane_no
)

select
    l.drive_id,
    l.actor_id,
    l.frame,
    n.lane_id,
    case when l.inside then 0.0 else l.edge_dist end as dist_m,
    atan2(sin(l.heading_rad - l.lane_heading), cos(l.heading_rad - l.lane_heading)) as heading_diff_rad
from per_lane as l
inner join lane_names as n on n.lane_no = l.lane_no
where l.inside or l.edge_dist <= $range_m
