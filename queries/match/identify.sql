-- match: identify
-- grain: one row per match of one scenario, with a stable id and the run's identity
-- reads: scenario_match (the scenario's match query: one row per match and phase, each with the match interval)
-- params: $scenario, $scenario_version, $params_hash
select
    md5(concat_ws('|', $scenario, m.drive_id, m.ego_id, m.actor_id, cast(m.start_frame as varchar))) as match_id,
    $scenario as scenario,
    $scenario_version as scenario_version,
    $params_hash as params_hash,
    m.end_s - m.start_s as duration_s,
    m.drive_id,
    m.ego_id,
    m.actor_id,
    m.start_frame,
    m.end_frame,
    m.start_s,
    m.end_s,
    m.drive_key,
    m.ego_key,
    m.actor_key
from scenario_match as m
where m.phase_index = 1
