-- match: identify
-- grain: one row per match of one scenario, with a stable id and the run's identity
-- reads: scenario_match (the scenario's match query)
-- params: $scenario, $scenario_version, $params_hash
select
    md5(concat_ws('|', $scenario, drive_id, ego_id, actor_id, cast(start_frame as varchar))) as match_id,
    $scenario as scenario,
    $scenario_version as scenario_version,
    $params_hash as params_hash,
    drive_id,
    ego_id,
    actor_id,
    start_frame,
    end_frame,
    start_s,
    end_s,
    end_s - start_s as duration_s
from scenario_match
