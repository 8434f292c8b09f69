-- junctions: crossing_pairs
-- grain: one row per (drive_id, ego_id, ego_passage, actor_id, actor_passage): an ego and a related actor
--        near or in the same junction at the same time, whose paths through it may cross
-- reads: relations, junction_frames
-- params: none
select distinct
    r.drive_id,
    r.ego_id,
    e.passage as ego_passage,
    r.actor_id,
    a.passage as actor_passage,
    e.junction_id
from relations as r
inner join junction_frames as e
    on r.drive_id = e.drive_id and r.ego_id = e.actor_id and r.frame = e.frame
inner join junction_frames as a
    on r.drive_id = a.drive_id and r.actor_id = a.actor_id and r.frame = a.frame
    and e.junction_id = a.junction_id
