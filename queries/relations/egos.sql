-- relations: egos
-- grain: one row per (drive_id, ego_id): the actors that play the SUT in this run, with their integer keys
--        (drive_key, ego_key: the ego's actor_key) that the later steps join on
-- reads: tracks, drive_inputs, run_drives
-- params: $ego_mode, $ego_every, $ego_actor_ids_csv, $ego_kinds_csv
--
-- ego_kinds_csv (',vehicle,truck,bus,motorcycle,emergency_vehicle,' unless --ego-kinds narrows it) are the kinds
-- that can be under test: a truck or a bus is a SUT like any car.
--   auto      the recorded ego where the drive has one, else every actor of an ego kind (NGSIM)
--   recorded  the recorded ego only; drives without one get status no_ego
--   all       every actor of an ego kind, and the recorded ego
--   every     every ego_every-th actor of an ego kind by actor_id order (1st, 1+N-th, ...), and the recorded ego
--   id        the actors whose actor_id is in the comma-separated list ego_actor_ids_csv (',a,b,'), in
--             every drive that has them
with

candidates as (
    select distinct
        t.drive_id,
        t.drive_key,
        t.actor_id,
        t.actor_key,
        t.is_ego,
        t.kind,
        d.ego_actor_id,
        instr($ego_kinds_csv, ',' || t.kind || ',') > 0 as can_be_sut
    from tracks as t
    inner join run_drives as r
        on t.drive_id = r.drive_id
    inner join drive_inputs as d
        on t.drive_id = d.drive_id
    where d.status = 'ingested'
),

numbered as (
    select
        *,
        row_number() over (partition by drive_key, can_be_sut order by actor_key) as sut_number
    from candidates
)

select distinct
    drive_id,
    actor_id as ego_id,
    drive_key,
    actor_key as ego_key
from numbered
where ($ego_mode = 'recorded' and is_ego)
    or ($ego_mode = 'auto' and (is_ego or (ego_actor_id is null and can_be_sut)))
    or ($ego_mode = 'all' and (is_ego or can_be_sut))
    or ($ego_mode = 'every' and (is_ego or (can_be_sut and (sut_number - 1) % $ego_every = 0)))
    or ($ego_mode = 'id' and instr($ego_actor_ids_csv, ',' || actor_id || ',') > 0)
