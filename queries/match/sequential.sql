-- match: sequential
-- grain: one row per match of a scenario whose phases (up to four) follow one another, with each phase's
--        interval (p1_* .. p4_*; NULL past the scenario's last phase) and the match interval [start, end]
-- reads: chain (match/chain.sql, over phase_islands: the stretches of consecutive frames in which each
--        phase's conditions hold), tracks
-- params: $phase_count
--
-- A match is a chain: phase 1 starts where one of its islands starts, and each next phase takes over from
-- the phase before it at its transition frame, while that phase still holds (or right after its last frame):
--   * if an island of the next phase starts after the current phase started, the next phase begins where
--     that island starts (the earliest such island): "the actor enters the encroachment area";
--   * otherwise, if the next phase already holds, it begins right after the current phase's island ends when
--     it still holds then ("the other car finished crossing, the Ego is still in the junction"), else at once,
--     one frame after the current phase began.
-- Phase k then lasts from its transition frame to the frame before the next transition; the last phase lasts
-- to the end of its island. Of several chains from one start, the one with the earliest transitions is kept.
-- The scenarios that use this query have no phase duration limits.
with

chosen as (
    -- per start, the complete chain with the earliest transitions
    select
        drive_id,
        ego_id,
        actor_id,
        chain_start_frame,
        min(path_key) as path_key
    from chain
    where phase_index = $phase_count
    group by drive_id, ego_id, actor_id, chain_start_frame
),

steps as (
    -- the phases of the chosen chains: the rows whose key is a prefix of the chosen key
    select
        c.drive_id,
        c.ego_id,
        c.actor_id,
        c.chain_start_frame,
        c.phase_index,
        c.phase_start_frame,
        c.island_end_frame
    from chain as c
    inner join chosen as k
        on c.drive_id = k.drive_id and c.ego_id = k.ego_id and c.actor_id = k.actor_id
        and c.chain_start_frame = k.chain_start_frame
        and starts_with(k.path_key, c.path_key)
),

phases as (
    select
        s.*,
        coalesce(
            lead(s.phase_start_frame) over (
                partition by s.drive_id, s.ego_id, s.actor_id, s.chain_start_frame order by s.phase_index
            ) - 1,
            s.island_end_frame
        ) as phase_end_frame
    from steps as s
),

timed as (
    select
        p.*,
        ts.t_s as phase_start_s,
        te.t_s as phase_end_s
    from phases as p
    inner join tracks as ts
        on p.drive_id = ts.drive_id and p.ego_id = ts.actor_id and p.phase_start_frame = ts.frame
    inner join tracks as te
        on p.drive_id = te.drive_id and p.ego_id = te.actor_id and p.phase_end_frame = te.frame
)

select
    drive_id,
    ego_id,
    actor_id,
    min(phase_start_frame) as start_frame,
    max(phase_end_frame) as end_frame,
    min(phase_start_s) as start_s,
    max(phase_end_s) as end_s,
    max(case when phase_index = 1 then phase_start_frame end) as p1_start_frame,
    max(case when phase_index = 1 then phase_end_frame end) as p1_end_frame,
    max(case when phase_index = 1 then phase_start_s end) as p1_start_s,
    max(case when phase_index = 1 then phase_end_s end) as p1_end_s,
    max(case when phase_index = 2 then phase_start_frame end) as p2_start_frame,
    max(case when phase_index = 2 then phase_end_frame end) as p2_end_frame,
    max(case when phase_index = 2 then phase_start_s end) as p2_start_s,
    max(case when phase_index = 2 then phase_end_s end) as p2_end_s,
    max(case when phase_index = 3 then phase_start_frame end) as p3_start_frame,
    max(case when phase_index = 3 then phase_end_frame end) as p3_end_frame,
    max(case when phase_index = 3 then phase_start_s end) as p3_start_s,
    max(case when phase_index = 3 then phase_end_s end) as p3_end_s,
    max(case when phase_index = 4 then phase_start_frame end) as p4_start_frame,
    max(case when phase_index = 4 then phase_end_frame end) as p4_end_frame,
    max(case when phase_index = 4 then phase_start_s end) as p4_start_s,
    max(case when phase_index = 4 then phase_end_s end) as p4_end_s
from timed
group by drive_id, ego_id, actor_id, chain_start_frame
