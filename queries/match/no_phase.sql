-- match: no_phase
-- grain: no rows: stands in for phase_<k> beyond a scenario's last phase, so that match/phase_runs.sql reads
--        phase_1 .. phase_4 whatever the number of phases
-- reads: phase_1
-- params: none
select
    drive_id,
    ego_id,
    actor_id,
    frame,
    t_s,
    segment,
    holds
from phase_1
where false
