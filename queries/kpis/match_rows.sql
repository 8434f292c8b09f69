-- kpis: match_rows
-- grain: one row per (match_id, frame) of the match interval [start_frame, end_frame] at which the ego or the
--        actor has a track row: the rows of tracks and relations the KPI and sample queries read
-- reads: scenario_matches, tracks, relations
-- params: none
--
-- The KPIs of a few hundred matches need the rows inside their intervals only: they are taken here once per
-- scenario, by an interval join of the matches with tracks and relations on the integer keys (drive_key, ego_key,
-- actor_key) and the frame range, and every KPI and sample query reads them by match_id (and frame).
--   ego_tracked, actor_tracked                      the ego (the actor) has a track row at the frame
--   ego_speed_mps, ego_accel_mps2                   the ego's tracks.speed_mps and accel_mps2 at the frame
--   actor_kind, actor_speed_mps, actor_accel_mps2   the actor's tracks.kind, speed_mps and accel_mps2
--   related                                         relations has the pair at the frame (within relation range)
--   lon_gap_m, adjacent_side, ttc_s, mttc_s         the pair's relations columns at the frame
-- A value is NULL where its row is missing (not tracked, not related).
with

keyed as (
    -- each match with a key of its own (match_key) for the joins and groups below; scenario_matches carries the
    -- integer keys of its drive, ego and actor (match/identify.sql)
    select
        match_id,
        drive_key,
        ego_key,
        actor_key,
        start_frame,
        end_frame,
        row_number() over (order by match_id) as match_key
    from scenario_matches
),

roles as (
    select match_key, drive_key, ego_key as actor_key, start_frame, end_frame, 1 as is_ego from keyed
    union all
    select match_key, drive_key, actor_key, start_frame, end_frame, 0 as is_ego from keyed
),

tracked as (
    -- the ego's and the actor's track rows in the interval, side by side per frame
    select
        r.match_key,
        t.frame,
        max(r.is_ego) = 1 as ego_tracked,
        min(r.is_ego) = 0 as actor_tracked,
        max(case when r.is_ego = 1 then t.speed_mps end) as ego_speed_mps,
        max(case when r.is_ego = 1 then t.accel_mps2 end) as ego_accel_mps2,
        max(case when r.is_ego = 0 then t.kind end) as actor_kind,
        max(case when r.is_ego = 0 then t.speed_mps end) as actor_speed_mps,
        max(case when r.is_ego = 0 then t.accel_mps2 end) as actor_accel_mps2
    from roles as r
    inner join tracks as t
        on r.drive_key = t.drive_key and r.actor_key = t.actor_key
        and t.frame between r.start_frame and r.end_frame
    group by r.match_key, t.frame
),

related as (
    select
        k.match_key,
        p.frame,
        p.lon_gap_m,
        p.adjacent_side,
        p.ttc_s,
        p.mttc_s
    from keyed as k
    inner join relations as p
        on k.drive_key = p.drive_key and k.ego_key = p.ego_key and k.actor_key = p.actor_key
        and p.frame between k.start_frame and k.end_frame
)

select
    k.match_id,
    t.frame,
    t.ego_tracked,
    t.actor_tracked,
    t.ego_speed_mps,
    t.ego_accel_mps2,
    t.actor_kind,
    t.actor_speed_mps,
    t.actor_accel_mps2,
    r.match_key is not null as related,
    r.lon_gap_m,
    r.adjacent_side,
    r.ttc_s,
    r.mttc_s
from tracked as t
inner join keyed as k
    on t.match_key = k.match_key
left join related as r
    on t.match_key = r.match_key and t.frame = r.frame
