-- kpis: base_vehicle_scenario
-- grain: one row per match: the vehicle_actor's KPIs and the Ego's TTC/MTTC to it, spec units
-- reads: scenario_matches, match_rows
-- params: $mph_per_mps (unit constant)
--
-- ego_min_ttc_to_vehicle_s / ego_min_mttc_to_vehicle_s: least per-frame ttc_s / mttc_s of the pair's relations
-- over the interval (match_rows), NULLs skipped; NULL when the pair never closes in (no defined sample).
with

actor as (
    select
        m.match_id,
        max(r.actor_kind) as vehicle_object_kind,
        max(m.actor_id) as vehicle_tracking_id,
        -- mean of speeds in whole micrometres per second: an integer sum does not depend on the order
        -- in which threads add the rows, so the KPI is the same to the last bit on every run
        cast(sum(cast(round(r.actor_speed_mps * 1e6) as decimal(38, 0))) as double)
            / nullif(count(r.actor_speed_mps), 0) / 1e6 * $mph_per_mps as vehicle_avg_speed_mph,
        max(r.actor_speed_mps) * $mph_per_mps as vehicle_max_speed_mph,
        min(r.actor_speed_mps) * $mph_per_mps as vehicle_min_speed_mph,
        max(r.actor_accel_mps2) as vehicle_max_lon_acceleration_mpsps,
        min(r.actor_accel_mps2) as vehicle_min_lon_acceleration_mpsps
    from scenario_matches as m
    inner join match_rows as r
        on m.match_id = r.match_id
    where r.actor_tracked
    group by m.match_id
),

risk as (
    select
        match_id,
        min(ttc_s) as ego_min_ttc_to_vehicle_s,
        min(mttc_s) as ego_min_mttc_to_vehicle_s
    from match_rows
    where related
    group by match_id
)

select
    actor.*,
    risk.ego_min_ttc_to_vehicle_s,
    risk.ego_min_mttc_to_vehicle_s
from actor
left join risk
    on actor.match_id = risk.match_id
