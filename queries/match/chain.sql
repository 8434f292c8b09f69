-- match: chain
-- grain: one row per (drive_key, ego_key, actor_key, chain_start_frame, path_key): a chain of phases from a
--        phase-1 run, as far as it gets (phase_index = the phase it has reached); `explain` reads the
--        partial ones, match/sequential.sql the complete ones
-- reads: phase_runs (the runs not flagged as jitter)
-- params: $phase_count
--
-- The one rule by which sequential phases meet (docs/semantics.md, "Phases and matches"). From phase k, begun
-- at phase_start_frame in a run that ends at run_end_frame, phase k+1 begins
--   * where a run of phase k+1 starts, if it starts after phase_start_frame and at most max_gap after phase k
--     stopped holding (by run_end_frame + 1 + max_gap_frames): the next phase takes over from the current
--     one. Starting one frame after the last frame of phase k is exactly contiguous; the frames of a gap
--     between them (at most max_gap, the same tolerance that bridges a gap inside a phase) count to phase k;
--   * else, if a run of phase k+1 already holds at phase_start_frame + 1 (the phases overlap): right after
--     run_end_frame when it lasts beyond it, otherwise at phase_start_frame + 1 (phase k lasts one frame).
-- path_key is the chain's transition frames, zero-padded and concatenated: the least key has the earliest
-- transitions.
with recursive chain as (
    select
        drive_key,
        ego_key,
        actor_key,
        1 as phase_index,
        start_frame as chain_start_frame,
        start_frame as phase_start_frame,
        end_frame as run_end_frame,
        max_gap_frames,
        lpad(cast(start_frame as varchar), 12, '0') as path_key
    from phase_runs
    where phase_index = 1 and not jitter

    union all

    select
        c.drive_key,
        c.ego_key,
        c.actor_key,
        c.phase_index + 1 as phase_index,
        c.chain_start_frame,
        case
            when j.start_frame > c.phase_start_frame then j.start_frame
            when j.end_frame >= c.run_end_frame + 1 then c.run_end_frame + 1
            else c.phase_start_frame + 1
        end
            as phase_start_frame,
        j.end_frame as run_end_frame,
        c.max_gap_frames,
        c.path_key || lpad(cast(
            case
            when j.start_frame > c.phase_start_frame then j.start_frame
            when j.end_frame >= c.run_end_frame + 1 then c.run_end_frame + 1
            else c.phase_start_frame + 1
        end
            as varchar), 12, '0') as path_key
    from chain as c
    inner join phase_runs as j
        on c.drive_key = j.drive_key and c.ego_key = j.ego_key and c.actor_key = j.actor_key
        and j.phase_index = c.phase_index + 1
    where c.phase_index < $phase_count
        and not j.jitter
        and (
            (j.start_frame > c.phase_start_frame and j.start_frame <= c.run_end_frame + 1 + c.max_gap_frames)
            or (j.start_frame <= c.phase_start_frame and j.end_frame >= c.phase_start_frame + 1)
        )
)

select * from chain
