-- kpis: base_scenario
-- grain: one row per match: the Ego's KPIs over the match interval [start_frame, end_frame], spec units
-- reads: scenario_matches, tracks
-- params: $mph_per_mps (unit constant)
select
    m.match_id,
    max(e.accel_mps2) as ego_max_lon_acceleration_mpsps,
    min(e.accel_mps2) as ego_min_lon_acceleration_mpsps,
    min(e.speed_mps) * $mph_per_mps as ego_min_speed_mph,
    avg(e.speed_mps) * $mph_per_mps as ego_avg_speed_mph,
    max(e.speed_mps) * $mph_per_mps as ego_max_speed_mph,
    max(m.end_s) - max(m.start_s) as interval_duration_s,
    max(case when e.frame = m.start_frame then e.speed_mps end) * $mph_per_mps as ego_speed_at_start_mph
from scenario_matches as m
inner join tracks as e
    on m.drive_id = e.drive_id and m.ego_id = e.actor_id
    and e.frame between m.start_frame and m.end_frame
group by m.match_id
