-- match: phase_islands
-- grain: one row per (phase_index, drive_id, ego_id, actor_id, island): consecutive frames in which a phase's
--        conditions hold, for match/sequential.sql
-- reads: phase_frames (one row per drive_id, ego_id, actor_id, frame, with a boolean per phase: phase_1 ..
--        phase_4, NULL or false where the phase does not hold or the scenario has fewer phases)
-- params: none
with

holding as (
    select distinct drive_id, ego_id, actor_id, frame, 1 as phase_index from phase_frames where phase_1
    union all
    select distinct drive_id, ego_id, actor_id, frame, 2 as phase_index from phase_frames where phase_2
    union all
    select distinct drive_id, ego_id, actor_id, frame, 3 as phase_index from phase_frames where phase_3
    union all
    select distinct drive_id, ego_id, actor_id, frame, 4 as phase_index from phase_frames where phase_4
),

islands as (
    select
        *,
        frame - row_number() over (partition by drive_id, ego_id, actor_id, phase_index order by frame) as island
    from holding
)

select
    phase_index,
    drive_id,
    ego_id,
    actor_id,
    min(frame) as start_frame,
    max(frame) as end_frame
from islands
group by phase_index, drive_id, ego_id, actor_id, island
