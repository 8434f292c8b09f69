-- junctions: actor_paths
-- grain: one row per (drive_id, actor_id, frame) of the egos and of the actors related to them
-- reads: egos, relations, tracks
-- params: none
--
-- Joined and windowed on the integer keys (drive_key, actor_key), which each row carries beside the ids.
--
-- The actors are those of relations, so of the kinds the run's scenarios can use (relations.sql): every kind in a
-- run of a scenario that leaves relation_kinds unset, as the left turn does; a junction scenario that declared
-- relation_kinds would get passages for those kinds only.
--
-- s_m is the distance the box centre has travelled since the actor's first row: a position along the actor's
-- own path, so offsets from a junction's start and end are differences of s_m (the junction scenarios need
-- no other actors). Each step is the displacement projected on the actor's heading, so position jitter (a
-- perception stack's 0.2 m) cancels out instead of adding up: the length of jittery steps would make a car
-- waiting at the line travel metres. length_m (the box length) lets junction_frames measure from the front.
with

actors as (
    select drive_key, ego_key as actor_key from egos
    union
    select distinct drive_key, actor_key from relations
),

steps as (
    select
        t.drive_id,
        t.actor_id,
        t.drive_key,
        t.actor_key,
        t.frame,
        t.t_s,
        t.heading_rad,
        t.length_m,
        (t.x_m - lag(t.x_m) over w) * cos(t.heading_rad) + (t.y_m - lag(t.y_m) over w) * sin(t.heading_rad)
            as step_m
    from tracks as t
    inner join actors as a
        on t.drive_key = a.drive_key and t.actor_key = a.actor_key
    window w as (partition by t.drive_key, t.actor_key order by t.frame)
),

path as (
    select
        drive_id,
        actor_id,
        frame,
        t_s,
        heading_rad,
        length_m,
        coalesce(sum(step_m) over (
            partition by drive_key, actor_key order by frame rows between unbounded preceding and current row
        ), 0.0) as s_m,
        min(frame) over (partition by drive_key, actor_key) as first_frame,
        max(frame) over (partition by drive_key, actor_key) as last_frame,
        drive_key,
        actor_key
    from steps
)

select * from path
