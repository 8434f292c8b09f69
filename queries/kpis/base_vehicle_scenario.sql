-- kpis: base_vehicle_scenario
-- grain: one row per match: the vehicle_actor's KPIs and the Ego's TTC/MTTC to it, spec units
-- reads: scenario_matches, tracks, relations
-- params: $mph_per_mps (unit constant)
--
-- ego_min_ttc_to_vehicle_s / ego_min_mttc_to_vehicle_s: least per-frame ttc_s / mttc_s of relations over the
-- interval, NULLs skipped; NULL when the pair never closes in (no defined sample).
with

actor as (
    select
        m.match_id,
        max(a.kind) as vehicle_object_kind,
        max(a.actor_id) as vehicle_tracking_id,
        -- mean of speeds in whole micrometres per second: an integer sum does not depend on the order
        -- in which threads add the rows, so the KPI is the same to the last bit on every run
        cast(sum(cast(round(a.speed_mps * 1e6) as decimal(38, 0))) as double)
            / nullif(count(a.speed_mps), 0) / 1e6 * $mph_per_mps as vehicle_avg_speed_mph,
        max(a.speed_mps) * $mph_per_mps as vehicle_max_speed_mph,
        min(a.speed_mps) * $mph_per_mps as vehicle_min_speed_mph,
        max(a.accel_mps2) as vehicle_max_lon_acceleration_mpsps,
        min(a.accel_mps2) as vehicle_min_lon_acceleration_mpsps
    from scenario_matches as m
    inner join tracks as a
        on m.drive_id = a.drive_id and m.actor_id = a.actor_id
        and a.frame between m.start_frame and m.end_frame
    group by m.match_id
),

risk as (
    select
        m.match_id,
        min(r.ttc_s) as ego_min_ttc_to_vehicle_s,
        min(r.mttc_s) as ego_min_mttc_to_vehicle_s
    from scenario_matches as m
    inner join relations as r
        on m.drive_id = r.drive_id and m.ego_id = r.ego_id and m.actor_id = r.actor_id
        and r.frame between m.start_frame and m.end_frame
    group by m.match_id
)

select
    actor.*,
    risk.ego_min_ttc_to_vehicle_s,
    risk.ego_min_mttc_to_vehicle_s
from actor
left join risk
    on actor.match_id = risk.match_id
