-- coverage: object_at_sample
-- grain: one row per (match_id, sample): the object's kind at each sampling event of the match
--        (match/samples.sql); each coverage item keeps the row of the event its `sample` names
-- reads: match_samples, match_rows (kpis/match_rows.sql)
-- params: none
--
--   object_kind   the object's kind at the sample's frame
select
    s.match_id,
    s.sample,
    r.actor_kind as object_kind
from match_samples as s
left join match_rows as r
    on s.match_id = r.match_id and s.frame = r.frame
