-- replay: windows
-- grain: one row per match to replay: the frames shown, the match plus margin_s either side
-- reads: matches, drive_inputs, replay_ids
-- params: $margin_s
select
    m.match_id,
    m.scenario,
    m.drive_id,
    d.map_id,
    m.ego_id,
    m.actor_id,
    m.start_frame,
    m.end_frame,
    m.start_s,
    m.end_s,
    m.params_hash,
    d.dt_s,
    m.start_frame - cast(round($margin_s / nullif(d.dt_s, 0)) as bigint) as first_frame,
    m.end_frame + cast(round($margin_s / nullif(d.dt_s, 0)) as bigint) as last_frame
from matches as m
inner join drive_inputs as d
    on m.drive_id = d.drive_id
inner join replay_ids as r
    on m.match_id = r.match_id
