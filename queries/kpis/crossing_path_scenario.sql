-- kpis: crossing_path_scenario
-- grain: one row per match: the post-encroachment time between the Ego and the vehicle_actor
-- reads: scenario_matches, phase_1 (the scenario's first phase, which carries pet_s of the pair's junction
--        passages where the match began)
-- params: none
--
--   pet_between_sut_and_npc_s  the second box's first frame in the encroachment area minus the first box's
--                              first frame after leaving it, to the sample; NULL when both were in the area
--                              at once or one never crossed it (docs/semantics.md)
select
    m.match_id,
    min(f.pet_s) as pet_between_sut_and_npc_s
from scenario_matches as m
inner join phase_1 as f
    on m.drive_id = f.drive_id and m.ego_id = f.ego_id and m.actor_id = f.actor_id
    and f.frame = m.start_frame and f.holds
group by m.match_id
