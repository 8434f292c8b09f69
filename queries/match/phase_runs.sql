-- match: phase_runs
-- grain: one row per (phase_index, drive_key, ego_key, actor_key, segment, run): a stretch of frames in which a
--        phase holds, gaps of at most max_gap bridged, flagged as jitter when it held at fewer than half its frames
-- reads: phase_frames (the frames at which each phase of the scenario holds, match/phase_frames.sql), drive_inputs
-- params: $max_gap_s
--
-- A run is a maximal stretch of frames of one (ego, actor) pair and one segment in which the phase holds, where
-- an interruption of at most max_gap (frames missing from the tracks, or frames at which the phase's condition
-- is false) does not end it: a missed detection, or measurement jitter across a threshold, does not split a
-- phase. With max_gap = 0 a run is exactly a stretch of consecutive frames. (The other half of the rule, a match
-- shorter than max_gap is jitter, is in match/sequential.sql: a phase may hold briefly within a longer match.)
--   max_gap_frames   floor(max_gap / dt_s): the longest interruption bridged, in frames
--   bridged_frames   frames inside the run at which the phase did not hold (or that are missing): what was
--                    bridged (`logiq-sql explain` lists them)
--   jitter           the run held at fewer than half of its frames (2 * held < span): a condition that
--                    measurement noise makes true now and then, not an episode, so match/chain.sql skips it
--                    (explain lists it). Bridging, this majority and the shortest match (match/sequential.sql)
--                    make one debouncing rule (docs/semantics.md, "Decision (gaps and jitter)").
-- Runs never span two segments (e.g. two lane runs of the ego).
with

stepped as (
    select
        h.*,
        cast(floor($max_gap_s / nullif(d.dt_s, 0) + 1e-9) as bigint) as max_gap_frames,
        h.frame - lag(h.frame) over (
            partition by h.phase_index, h.drive_key, h.ego_key, h.actor_key, h.segment order by h.frame
        ) as step
    from phase_frames as h
    inner join drive_inputs as d
        on h.drive_key = d.drive_key
),

numbered as (
    select
        *,
        sum(case when step is null or step - 1 > max_gap_frames then 1 else 0 end) over (
            partition by phase_index, drive_key, ego_key, actor_key, segment
            order by frame rows between unbounded preceding and current row
        ) as run
    from stepped
)

select
    phase_index,
    drive_key,
    ego_key,
    actor_key,
    segment,
    run,
    min(frame) as start_frame,
    max(frame) as end_frame,
    min(t_s) as start_s,
    max(t_s) as end_s,
    max(max_gap_frames) as max_gap_frames,
    max(frame) - min(frame) + 1 - count(*) as bridged_frames,
    2 * count(*) < max(frame) - min(frame) + 1 as jitter
from numbered
group by phase_index, drive_key, ego_key, actor_key, segment, run
