-- match: single_phase
-- grain: one row per match of a one-phase scenario: the phase interval is the match interval
-- reads: phase_1 (the scenario's only phase)
-- params: none
select
    drive_id,
    ego_id,
    actor_id,
    start_frame,
    end_frame,
    start_s,
    end_s,
    start_frame as p1_start_frame,
    end_frame as p1_end_frame,
    start_s as p1_start_s,
    end_s as p1_end_s
from phase_1
