-- benchmark, not wired in: the grid cells that track rows occupy (benchmarks.localise_join.lane_grid builds the
-- lane pieces of these only)
-- grain: one row per (map_no, cell_x, cell_y)
-- reads: tracks (staged), _drive_maps (drive_id, map_no: the drives to localise and their maps)
-- params: $cells_per_m (1 / the grid's cell size), as in track_lanes.sql
select distinct
    m.map_no,
    cast(floor(t.x_m * $cells_per_m) as bigint) as cell_x,
    cast(floor(t.y_m * $cells_per_m) as bigint) as cell_y
from tracks as t
inner join _drive_maps as m on m.drive_id = t.drive_id
where t.kind not in ('object', 'fod', 'sign')
