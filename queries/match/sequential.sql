-- match: sequential
-- grain: one row per (match, phase) of a scenario: the match interval [start, end] and the phase's interval in it
--        (phase_index; phase_start_*, phase_end_*), one row for each of the scenario's phases; the pair by its ids
--        and its integer keys (drive_key, ego_key, actor_key), on which every join and window here is made
-- reads: chain (match/chain.sql over phase_runs), scenario_phases (the phases' duration limits), tracks (the ego's
--        times, and the ids of the keys for the output), drive_inputs
-- params: $phase_count, $max_gap_s
--
-- Every scenario, whatever its number of phases, is matched by this query (docs/semantics.md, "Phases and matches"):
--   1. A match is a complete chain (chain.sql): phase k lasts from its transition frame to the frame before
--      the next phase's transition; the last phase to the end of its run. Of several chains from one start,
--      the one with the earliest transitions is kept.
--   2. Durations have one meaning: end_s - start_s of the phase's interval in the match.
--      Maximum: the first phase keeps its last max seconds before the transition, the last phase its first max
--      seconds after it (so a long episode gives one match around each transition); a middle phase longer
--      than its maximum gives no match. A one-phase scenario's run longer than the maximum is cut into
--      consecutive pieces of at most the maximum from its start (floor(max / dt_s) + 1 frames), each a match:
--      no part of the episode is lost.
--      Minimum: then every phase must last at least its minimum.
--   3. Jitter: a chain that lasts less than max_gap altogether (a distance dipping under its limit for a frame or
--      two on noisy positions) is not an episode and gives no match; the other half of bridging gaps of at most
--      max_gap (match/phase_runs.sql). A phase may still hold briefly inside a longer chain.
-- Timestamps are compared with a 1 us tolerance, so a 3 s limit keeps 3 s of 0.1 s samples whatever the
-- floating-point rounding of t_s.
with

chosen as (
    -- per start, the complete chain with the earliest transitions
    select
        drive_key,
        ego_key,
        actor_key,
        chain_start_frame,
        min(path_key) as path_key
    from chain
    where phase_index = $phase_count
    group by drive_key, ego_key, actor_key, chain_start_frame
),

steps as (
    -- the phases of the chosen chains: the rows whose key is a prefix of the chosen key
    select
        c.drive_key,
        c.ego_key,
        c.actor_key,
        c.chain_start_frame,
        c.phase_index,
        c.phase_start_frame,
        c.run_end_frame
    from chain as c
    inner join chosen as k
        on c.drive_key = k.drive_key and c.ego_key = k.ego_key and c.actor_key = k.actor_key
        and c.chain_start_frame = k.chain_start_frame
        and starts_with(k.path_key, c.path_key)
),

phases as (
    select
        s.*,
        coalesce(
            lead(s.phase_start_frame) over (
                partition by s.drive_key, s.ego_key, s.actor_key, s.chain_start_frame order by s.phase_index
            ) - 1,
            s.run_end_frame
        ) as phase_end_frame
    from steps as s
),

spans as (
    -- per chain: its frames, where phase 1 ends and where the last phase begins, and the limits that trim them
    select
        p.drive_key,
        p.ego_key,
        p.actor_key,
        p.chain_start_frame,
        min(p.phase_start_frame) as first_frame,
        max(p.phase_end_frame) as last_frame,
        max(case when p.phase_index = 1 then p.phase_end_frame end) as p1_end_frame,
        max(case when p.phase_index = $phase_count then p.phase_start_frame end) as last_start_frame,
        max(case when p.phase_index = 1 then l.max_s end) as first_max_s,
        max(case when p.phase_index = $phase_count then l.max_s end) as last_max_s
    from phases as p
    inner join scenario_phases as l
        on p.phase_index = l.phase_index
    group by p.drive_key, p.ego_key, p.actor_key, p.chain_start_frame
),

ego_tracks as (
    -- the track rows of the chains' egos: the three joins below build their hash tables on these, not on every
    -- track row (the left joins of `timed` build on their right side: all of tracks, 1 M rows at tier S)
    select t.drive_key, t.actor_key, t.frame, t.t_s
    from tracks as t
    inner join (select distinct drive_key, ego_key from spans) as s
        on t.drive_key = s.drive_key and t.actor_key = s.ego_key
),

pair_ids as (
    -- the ids of the chains' egos and actors, for the output
    select distinct t.drive_key, t.actor_key, t.drive_id, t.actor_id
    from tracks as t
    inner join (
        select drive_key, ego_key as actor_key from spans
        union all
        select drive_key, actor_key from spans
    ) as s
        on t.drive_key = s.drive_key and t.actor_key = s.actor_key
),

ego_frames as (
    -- the ego's frames over each chain; a one-phase chain is cut into pieces of at most its maximum
    select
        s.*,
        d.dt_s,
        e.frame,
        e.t_s,
        case
            when $phase_count = 1 and s.first_max_s is not null
                then floor((e.frame - s.first_frame) / (floor(s.first_max_s / nullif(d.dt_s, 0) + 1e-9) + 1))
            else 0
        end as piece
    from spans as s
    inner join drive_inputs as d
        on s.drive_key = d.drive_key
    inner join ego_tracks as e
        on s.drive_key = e.drive_key and s.ego_key = e.actor_key
        and e.frame between s.first_frame and s.last_frame
),

transitions as (
    -- the time phase 1 ends and the last phase begins, taken as `timed` takes them below: the frame's t_s, or
    -- frame * dt_s when the ego's track misses that frame (a bridged gap), so that the kept maximum and the
    -- measured duration agree
    select
        drive_key,
        ego_key,
        actor_key,
        chain_start_frame,
        piece,
        coalesce(max(case when frame = p1_end_frame then t_s end), max(p1_end_frame * dt_s)) as p1_end_s,
        coalesce(max(case when frame = last_start_frame then t_s end), max(last_start_frame * dt_s))
            as last_start_s
    from ego_frames
    group by drive_key, ego_key, actor_key, chain_start_frame, piece
),

kept as (
    -- the frames within the maximum of the first and the last phase, counted from the transitions
    select
        f.drive_key,
        f.ego_key,
        f.actor_key,
        f.chain_start_frame,
        f.piece,
        min(f.frame) as start_frame,
        max(f.frame) as end_frame
    from ego_frames as f
    inner join transitions as t
        on f.drive_key = t.drive_key and f.ego_key = t.ego_key and f.actor_key = t.actor_key
        and f.chain_start_frame = t.chain_start_frame and f.piece = t.piece
    where $phase_count = 1
        or (
            (f.frame > f.p1_end_frame or f.first_max_s is null or f.t_s >= t.p1_end_s - f.first_max_s - 1e-6)
            and (f.frame < f.last_start_frame or f.last_max_s is null
                or f.t_s <= t.last_start_s + f.last_max_s + 1e-6)
        )
    group by f.drive_key, f.ego_key, f.actor_key, f.chain_start_frame, f.piece
),

clipped as (
    select
        p.drive_key,
        p.ego_key,
        p.actor_key,
        p.chain_start_frame,
        k.piece,
        p.phase_index,
        greatest(p.phase_start_frame, k.start_frame) as phase_start_frame,
        least(p.phase_end_frame, k.end_frame) as phase_end_frame,
        l.min_s,
        l.max_s
    from phases as p
    inner join kept as k
        on p.drive_key = k.drive_key and p.ego_key = k.ego_key and p.actor_key = k.actor_key
        and p.chain_start_frame = k.chain_start_frame
    inner join scenario_phases as l
        on p.phase_index = l.phase_index
),

timed as (
    -- a transition frame may be missing from the ego's track (a bridged gap): its time is then frame * dt_s
    select
        c.*,
        coalesce(ts.t_s, c.phase_start_frame * d.dt_s) as phase_start_s,
        coalesce(te.t_s, c.phase_end_frame * d.dt_s) as phase_end_s
    from clipped as c
    inner join drive_inputs as d
        on c.drive_key = d.drive_key
    left join ego_tracks as ts
        on c.drive_key = ts.drive_key and c.ego_key = ts.actor_key and c.phase_start_frame = ts.frame
    left join ego_tracks as te
        on c.drive_key = te.drive_key and c.ego_key = te.actor_key and c.phase_end_frame = te.frame
),

matched as (
    -- per piece of a chain: whether every phase fits its durations, and the match interval
    select
        *,
        min(case
            when phase_end_s - phase_start_s >= coalesce(min_s, 0) - 1e-6
                and (max_s is null or phase_end_s - phase_start_s <= max_s + 1e-6) then 1
            else 0
        end) over (partition by drive_key, ego_key, actor_key, chain_start_frame, piece) as durations_ok,
        min(phase_start_frame) over (partition by drive_key, ego_key, actor_key, chain_start_frame, piece)
            as start_frame,
        max(phase_end_frame) over (partition by drive_key, ego_key, actor_key, chain_start_frame, piece) as end_frame,
        min(phase_start_s) over (partition by drive_key, ego_key, actor_key, chain_start_frame, piece) as start_s,
        max(phase_end_s) over (partition by drive_key, ego_key, actor_key, chain_start_frame, piece) as end_s,
        max(phase_end_s) over (partition by drive_key, ego_key, actor_key, chain_start_frame)
            - min(phase_start_s) over (partition by drive_key, ego_key, actor_key, chain_start_frame) as chain_s
    from timed
)

select
    e.drive_id,
    e.actor_id as ego_id,
    a.actor_id,
    m.start_frame,
    m.end_frame,
    m.start_s,
    m.end_s,
    m.phase_index,
    m.phase_start_frame,
    m.phase_end_frame,
    m.phase_start_s,
    m.phase_end_s,
    m.drive_key,
    m.ego_key,
    m.actor_key
from matched as m
inner join pair_ids as e
    on m.drive_key = e.drive_key and m.ego_key = e.actor_key
inner join pair_ids as a
    on m.drive_key = a.drive_key and m.actor_key = a.actor_key
where m.durations_ok = 1
    and m.chain_s >= $max_gap_s - 1e-6
