-- kpis: unprotected_left_turn
-- grain: one row per match: the vehicle_actor's traversal direction relative to the Ego
-- reads: scenario_matches, phase_1 (stop_in_green_light, at the junction passages where the match began)
-- params: none
--
--   traversal_relative_direction  <entry leg>_to_<exit leg> of the vehicle_actor's passage through the junction,
--                                 each leg classed against the Ego's entry leg (parallel, opposite, left,
--                                 right); unknown when a leg is not observed (docs/semantics.md)
select
    m.match_id,
    min(f.traversal_relative_direction) as traversal_relative_direction
from scenario_matches as m
inner join phase_1 as f
    on m.drive_id = f.drive_id and m.ego_id = f.ego_id and m.actor_id = f.actor_id
    and f.frame = m.start_frame and f.holds
group by m.match_id
