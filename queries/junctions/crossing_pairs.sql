-- junctions: crossing_pairs
-- grain: one row per (drive_id, ego_id, ego_passage, actor_id, actor_passage): an ego and a related actor
--        near or in the same junction at the same time, whose paths through it may cross
-- reads: relations, junction_frames, egos
-- params: none
--
-- Joined on the integer keys (drive_key, ego_key, actor_key), which each row carries beside the ids.
select distinct
    r.drive_id,
    r.ego_id,
    e.passage as ego_passage,
    r.actor_id,
    a.passage as actor_passage,
    e.junction_id,
    r.drive_key,
    r.ego_key,
    r.actor_key
from relations as r
inner join (
    -- the egos' junction frames: a small table, which the relation's rows are looked up in first
    select f.*
    from junction_frames as f
    inner join egos as g
        on f.drive_key = g.drive_key and f.actor_key = g.ego_key
) as e
    on r.drive_key = e.drive_key and r.ego_key = e.actor_key and r.frame = e.frame
inner join junction_frames as a
    on r.drive_key = a.drive_key and r.actor_key = a.actor_key and r.frame = a.frame
    and e.junction_id = a.junction_id
