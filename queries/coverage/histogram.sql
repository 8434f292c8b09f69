-- coverage: histogram
-- grain: one row per (scenario, item, bucket), empty buckets included, plus 'out_of_range' and 'missing'
--        rows per item so that no sampled value is dropped
-- reads: coverage_samples(scenario, match_id, item, value_num, value_text),
--        coverage_buckets(scenario, item, bucket_index, bucket, lo, hi, value_text)
-- params: none
--
-- Numeric buckets are half-open [lo, hi) in the item's unit (the sample was converted before bucketing);
-- enum buckets match value_text exactly. A value outside every bucket counts as 'out_of_range'; a NULL
-- sample (undefined value) counts as 'missing'. Samples are put in their buckets by two equi-joins (enum, numeric)
-- unioned, not one LEFT JOIN whose ON is an OR of conditions (Polars SQL cannot plan that): buckets of an item do
-- not overlap and a match has one sample per item, so each sample lands in at most one bucket.
with

bucketed as (
    -- the bucket of every sample that has one: enum buckets by their value, numeric ones by their range
    select
        s.scenario,
        s.item,
        s.match_id,
        b.bucket_index,
        b.bucket
    from coverage_samples as s
    inner join coverage_buckets as b
        on s.scenario = b.scenario and s.item = b.item and s.value_text = b.value_text
    where b.value_text is not null
    union all
    select
        s.scenario,
        s.item,
        s.match_id,
        b.bucket_index,
        b.bucket
    from coverage_samples as s
    inner join coverage_buckets as b
        on s.scenario = b.scenario and s.item = b.item
    where b.value_text is null and s.value_num >= b.lo and s.value_num < b.hi
),

placed as (
    select
        s.scenario,
        s.item,
        s.match_id,
        b.bucket_index,
        b.bucket,
        case
            when b.bucket is not null then b.bucket
            when s.value_num is null and s.value_text is null then 'missing'
            else 'out_of_range'
        end as landed_in
    from coverage_samples as s
    left join bucketed as b
        on s.scenario = b.scenario and s.item = b.item and s.match_id = b.match_id
),

counted as (
    select
        scenario,
        item,
        landed_in,
        count(*) as hits
    from placed
    group by scenario, item, landed_in
),

extras as (
    select distinct
        scenario,
        item,
        landed_in as bucket
    from counted
    where landed_in in ('missing', 'out_of_range')
),

all_buckets as (
    select scenario, item, bucket_index, bucket, lo, hi from coverage_buckets
    union all
    select scenario, item, cast(null as bigint) as bucket_index, bucket, cast(null as double) as lo,
        cast(null as double) as hi
    from extras
)

select
    b.scenario,
    b.item,
    b.bucket_index,
    b.bucket,
    b.lo,
    b.hi,
    coalesce(c.hits, 0) as hits
from all_buckets as b
left join counted as c
    on b.scenario = c.scenario and b.item = c.item and b.bucket = c.landed_in
