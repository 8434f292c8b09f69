-- kpis: base_scenario
-- grain: one row per match: the Ego's KPIs over the match interval [start_frame, end_frame], spec units
-- reads: scenario_matches, match_rows
-- params: $mph_per_mps (unit constant)
select
    m.match_id,
    max(r.ego_accel_mps2) as ego_max_lon_acceleration_mpsps,
    min(r.ego_accel_mps2) as ego_min_lon_acceleration_mpsps,
    min(r.ego_speed_mps) * $mph_per_mps as ego_min_speed_mph,
    -- mean of speeds in whole micrometres per second: an integer sum does not depend on the order
    -- in which threads add the rows, so the KPI is the same to the last bit on every run
    cast(sum(cast(round(r.ego_speed_mps * 1e6) as decimal(38, 0))) as double)
        / nullif(count(r.ego_speed_mps), 0) / 1e6 * $mph_per_mps as ego_avg_speed_mph,
    max(r.ego_speed_mps) * $mph_per_mps as ego_max_speed_mph,
    max(m.end_s) - max(m.start_s) as interval_duration_s
from scenario_matches as m
inner join match_rows as r
    on m.match_id = r.match_id
where r.ego_tracked
group by m.match_id
