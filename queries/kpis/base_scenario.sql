-- kpis: base_scenario
-- grain: one row per match: the Ego's KPIs over the match interval [start_frame, end_frame], spec units
-- reads: scenario_matches, tracks
-- params: $mph_per_mps (unit constant)
select
    m.match_id,
    max(e.accel_mps2) as ego_max_lon_acceleration_mpsps,
    min(e.accel_mps2) as ego_min_lon_acceleration_mpsps,
    min(e.speed_mps) * $mph_per_mps as ego_min_speed_mph,
    -- mean of speeds in whole micrometres per second: an integer sum does not depend on the order
    -- in which threads add the rows, so the KPI is the same to the last bit on every run
    cast(sum(cast(round(e.speed_mps * 1e6) as decimal(38, 0))) as double)
        / nullif(count(e.speed_mps), 0) / 1e6 * $mph_per_mps as ego_avg_speed_mph,
    max(e.speed_mps) * $mph_per_mps as ego_max_speed_mph,
    max(m.end_s) - max(m.start_s) as interval_duration_s
from scenario_matches as m
inner join tracks as e
    on m.drive_id = e.drive_id and m.ego_id = e.actor_id
    and e.frame between m.start_frame and m.end_frame
group by m.match_id
