"""Ingest's checks (``ingestion.clean_batch``, one set of rules over a batch of any size) and the Parquet reader's
one cast per chunk (``readers.parquet._drives_at_once``): a batch gives exactly what each drive alone gives, and the
reader what casting drive by drive gives: the same drives, rows, counts and messages, for a batch mixing good
drives with every kind of bad one. The reader reads the file once, in its order, whatever the chunk size, and
gives what one chunk of the whole file gives, also when the drives' rows are interleaved.
"""

from __future__ import annotations

from pathlib import Path

import duckdb
import numpy as np
import polars as pl
import pytest

from benchmarks.ingest_checks import same_drives
from logiq_sql import ingest
from logiq_sql.core.errors import InputError
from logiq_sql.ingestion import ingest as ingestion
from logiq_sql.ingestion.readers import parquet
from tests.helpers import TWO_LANES, Y1, actor, times

T = times(5)


def scene(drive_id: str) -> pl.DataFrame:
    return pl.concat([actor("ego", T, 100 + 10 * T, Y1, is_ego=True, drive_id=drive_id),
                      actor("a", T, 80 + 10 * T, Y1, drive_id=drive_id)])


def nth(*rows: int) -> pl.Expr:
    """True on these row numbers."""
    return pl.int_range(pl.len()).is_in(list(rows))


def mixed(frame: bool = False) -> tuple[pl.DataFrame, dict[str, float | None]]:
    """One tracks table of many drives, most spoiled in one way each, and each drive's dt_s for drives.parquet;
    ``frame``: with a frame column (else each row's frame is derived from t_s and dt_s)."""
    drives = {
        "good": scene("good"),
        "shuffled": scene("shuffled").sample(fraction=1.0, shuffle=True, seed=7),
        "unknown_kind": scene("unknown_kind").with_columns(kind=pl.when(nth(5)).then(pl.lit("car"))
                                                           .otherwise(pl.col("kind"))),
        "degrees": scene("degrees").with_columns(heading_rad=pl.lit(90.0)),
        "milliseconds": scene("milliseconds").with_columns(pl.col("t_s") * 1000),
        "millimetres": scene("millimetres").with_columns(pl.col("x_m") * 1000, pl.col("y_m") * 1000),
        "bad_rows": scene("bad_rows").with_columns(
            x_m=pl.when(nth(3)).then(float("nan")).when(nth(4)).then(2e8)
            .otherwise(pl.col("x_m")),
            t_s=pl.when(nth(7)).then(float("inf")).otherwise(pl.col("t_s")),
            actor_id=pl.when(nth(60)).then(None).otherwise(pl.col("actor_id")),
            kind=pl.when(nth(61)).then(None).otherwise(pl.col("kind"))),
        "broken_values": scene("broken_values").with_columns(
            speed_mps=pl.when(nth(10)).then(5000.0).otherwise(10.0),
            accel_mps2=pl.when(nth(11, 12)).then(-2000.0).when(nth(13)).then(float("inf")),
            heading_rad=pl.when(nth(14)).then(float("nan")).otherwise(0.0),
            length_m=pl.when(nth(15)).then(0.0).otherwise(pl.col("length_m")),
            width_m=pl.when(nth(16)).then(float("nan")).otherwise(pl.col("width_m"))),
        "duplicates": pl.concat([
            scene("duplicates"), scene("duplicates").head(3),  # exact copies
            scene("duplicates").filter((pl.col("actor_id") == "a") & (pl.col("t_s") == 2.5))
            .with_columns(pl.col("x_m") + 3),  # a contradiction
            scene("duplicates").filter((pl.col("actor_id") == "a") & (pl.col("t_s") == 2.0))
            .with_columns(pl.col("t_s") + 0.04, pl.col("x_m") + 0.4)]),  # a second sample in frame 20
        # a second sample in frame 20, after and before the others (a sort may keep either order of the two)
        "second_sample": pl.concat([scene("second_sample"), scene("second_sample").filter(
            (pl.col("actor_id") == "a") & (pl.col("t_s") == 2.0)).with_columns(pl.col("t_s") + 0.04)]),
        "second_sample_first": pl.concat([scene("second_sample_first").filter(
            (pl.col("actor_id") == "a") & (pl.col("t_s") == 2.0)).with_columns(pl.col("t_s") + 0.04),
            scene("second_sample_first")]),
        "every_row_bad": scene("every_row_bad").with_columns(x_m=pl.lit(float("nan"))),
        "two_egos": scene("two_egos").with_columns(is_ego=pl.lit(True)),
        "bad_period": scene("bad_period"),
        "long_period": scene("long_period"),
        "no_period": scene("no_period"),
        "contradicted_period": scene("contradicted_period"),
        "cyclist": scene("cyclist").with_columns(kind=pl.lit("cyclist"), length_m=pl.lit(None, pl.Float64)),
    }
    periods: dict[str, float | None] = {d: 0.1 for d in drives}
    periods.update(bad_period=-0.1, long_period=100.0, no_period=None, contradicted_period=0.05, listed_only=0.1)
    # two drives whose rows alternate in the file (a drive's rows need not be together)
    a, b = scene("alternating_a"), scene("alternating_b")
    alternating = pl.concat([a.with_row_index("_i"), b.with_row_index("_i")]).sort("_i", maintain_order=True)
    periods.update(alternating_a=0.1, alternating_b=0.1)
    tracks = pl.concat([*drives.values(), alternating.drop("_i")], how="diagonal_relaxed")
    if frame:
        tracks = tracks.with_columns(frame=(pl.col("t_s") * 10).round().cast(pl.Int64, strict=False))
        # one actor at one t_s in two frames: two rows that contradict each other
        same_t = scene("same_time").with_columns(frame=(pl.col("t_s") * 10).round().cast(pl.Int64))
        same_t = same_t.with_columns(t_s=pl.when(nth(30)).then(pl.col("t_s").shift()).otherwise(pl.col("t_s")))
        tracks = pl.concat([tracks, same_t], how="diagonal_relaxed")
        periods["same_time"] = 0.1
    return tracks, periods


def write(folder: Path, tracks: pl.DataFrame, periods: dict[str, float | None]) -> Path:
    folder.mkdir(parents=True)
    tracks.write_parquet(folder / "tracks.parquet")
    pl.DataFrame({"drive_id": list(periods), "dt_s": list(periods.values()), "map_id": "road"},
                 schema={"drive_id": pl.String, "dt_s": pl.Float64, "map_id": pl.String}
                 ).write_parquet(folder / "drives.parquet")
    pl.DataFrame(TWO_LANES).write_parquet(folder / "lanes.parquet")
    return folder


def drive_by_drive(monkeypatch: pytest.MonkeyPatch) -> None:
    """The reader's code before the cast per chunk: every drive cast on its own."""
    monkeypatch.setattr(parquet, "_drives_at_once", lambda *args: None)


@pytest.mark.parametrize("frame", [False, True])
def test_the_reader_casts_each_chunk_as_it_cast_each_drive(tmp_path, monkeypatch, frame):
    tracks, periods = mixed(frame)
    folder = write(tmp_path / "in", tracks, periods)
    at_once = []
    real = parquet._drives_at_once
    monkeypatch.setattr(parquet, "_drives_at_once", lambda *args: at_once.append(real(*args)) or at_once[-1])
    got = list(parquet.read_parquet(folder))
    assert at_once and all(drives is not None for drives in at_once)  # the chunk path was taken
    monkeypatch.undo()
    drive_by_drive(monkeypatch)
    want = list(parquet.read_parquet(folder))
    same_drives(got, want)
    assert {d.drive_id for d in want if d.reject_reason} == {"two_egos", "bad_period", "listed_only"}
    assert len(want) == len(periods)


def read_in_chunks(folder: Path, monkeypatch: pytest.MonkeyPatch, rows: int) -> tuple[list, list[str]]:
    """The drives read with chunks of ``rows`` rows (sorted by drive_id), and the plans of the reader's reads of
    the tracks file."""
    plans = []
    real_collect = pl.LazyFrame.collect

    def collect(self, *args, **kwargs):
        plan = self.explain()
        if "Parquet SCAN" in plan:
            plans.append(plan)
        return real_collect(self, *args, **kwargs)

    monkeypatch.setattr(parquet, "CHUNK_ROWS", rows)
    monkeypatch.setattr(pl.LazyFrame, "collect", collect)
    drives = sorted(parquet.read_parquet(folder), key=lambda d: d.drive_id)
    monkeypatch.undo()
    return drives, plans


@pytest.mark.parametrize("frame", [False, True])
def test_the_reader_reads_the_file_once_in_chunks_of_any_size(tmp_path, monkeypatch, frame):
    tracks, periods = mixed(frame)
    folder = write(tmp_path / "in", tracks, periods)
    whole, _ = read_in_chunks(folder, monkeypatch, tracks.height)
    for rows in (150, 333):  # chunk boundaries inside drives; the alternating drives wait for each other
        got, plans = read_in_chunks(folder, monkeypatch, rows)
        same_drives(got, whole)
        reads = [p for p in plans if "PROJECT 1/" not in p]  # besides one pass over drive_id
        assert len(reads) == -(-tracks.height // rows), "the file is read in its order, a chunk at a time"
        assert all("SLICE" in p and "SELECTION" not in p for p in reads), "never scanned whole for a chunk"
    got, _ = read_in_chunks(folder, monkeypatch, 7)  # the alternating drives outgrow what may wait: scanned for
    same_drives(got, whole)


def test_drives_too_interleaved_to_wait_for_are_read_by_filtered_scans(tmp_path, monkeypatch):
    """Rows dealt to the drives in turn: waiting for whole drives would hold the file, so the reader scans for
    the rest (memory stays bounded) and gives the same drives."""
    tracks = pl.concat([scene(f"d{i}").with_row_index("_i") for i in range(6)]).sort("_i", maintain_order=True)
    folder = write(tmp_path / "in", tracks.drop("_i"), {f"d{i}": 0.1 for i in range(6)})
    whole, _ = read_in_chunks(folder, monkeypatch, tracks.height)
    got, plans = read_in_chunks(folder, monkeypatch, 10)
    same_drives(got, whole)
    assert any("SELECTION" in p for p in plans)


def test_a_value_that_does_not_convert_still_yields_the_drives_before_it(tmp_path, monkeypatch):
    tracks = pl.concat([scene("first"), scene("second")]).with_columns(
        frame=pl.when(nth(150)).then(float("nan")).otherwise(pl.col("t_s") * 10))  # frame as floats
    folder = write(tmp_path / "in", tracks, {"first": 0.1, "second": 0.1})

    def until_error() -> tuple[list, str]:
        read = []
        with pytest.raises(InputError) as exc:
            for drive in parquet.read_parquet(folder):
                read.append(drive)  # noqa: PERF402 (the drives before the error count)
        return read, str(exc.value)

    got, says = until_error()
    drive_by_drive(monkeypatch)
    want, said = until_error()
    same_drives(got, want)
    assert [d.drive_id for d in got] == ["first"] and says == said
    assert says.startswith(f"{folder / 'tracks.parquet'}: column 'frame' is Float64, which does not convert to Int64")


@pytest.mark.parametrize("frame", [False, True])
def test_the_batch_checks_give_what_each_drive_checked_alone_gives(tmp_path, frame):
    tracks, periods = mixed(frame)
    drives = list(parquet.read_parquet(write(tmp_path / "in", tracks, periods)))
    cleaned = ingestion.clean_batch(drives)
    assert len(cleaned) == len(drives)
    for drive, got in zip(drives, cleaned, strict=True):
        (alone,) = ingestion.clean_batch([drive])
        if isinstance(alone, InputError):
            assert isinstance(got, InputError) and str(got) == str(alone), drive.drive_id
            continue
        (rows, dropped, reasons), (want, want_dropped, want_reasons) = got, alone
        assert rows.schema == want.schema and rows.equals(want, null_equal=True), drive.drive_id
        assert (dropped, reasons) == (want_dropped, want_reasons), drive.drive_id
        assert rows.equals(ingestion.clean_tracks(drive)[0], null_equal=True)
    passed = {d.drive_id: r for d, r in zip(drives, cleaned, strict=True) if not isinstance(r, InputError)}
    assert sorted(d for d, (rows, _, _) in passed.items() if rows.height) == sorted([
        "good", "shuffled", "bad_rows", "broken_values", "duplicates", "second_sample", "second_sample_first",
        "no_period", "cyclist", "alternating_a", "alternating_b",
        *(["contradicted_period", "same_time"] if frame else [])])
    assert passed["bad_rows"][2] == [
        "2 row(s) with a NULL, NaN or infinite t_s, x_m or y_m dropped",
        "1 row(s) with |x_m| or |y_m| above 1e+08 m or |t_s| above 1e+10 s dropped",
        "2 row(s) with a NULL actor_id, kind or frame dropped"]
    assert passed["broken_values"][2] == [
        "1 speed_mps value(s) beyond +-1000 set to NULL and derived from positions",
        "2 accel_mps2 value(s) beyond +-1000 set to NULL and derived from positions"]
    # a second sample in a frame: the one nearest to frame * dt_s kept, whichever order the two came in
    assert passed["second_sample"][0].drop("drive_id").equals(passed["second_sample_first"][0].drop("drive_id"))


@pytest.mark.parametrize("frame", [False, True])
def test_a_mixed_batch_ingests_as_drive_by_drive_and_as_each_drive_alone(tmp_path, monkeypatch, frame):
    tracks, periods = mixed(frame)
    folder = write(tmp_path / "in", tracks, periods)
    ingest("parquet", [folder], tmp_path / "batch.duckdb")
    with monkeypatch.context() as m:
        drive_by_drive(m)
        ingest("parquet", [folder], tmp_path / "drive_by_drive.duckdb")
    with monkeypatch.context() as m:
        m.setattr(ingestion, "BATCH_ROWS", 1)  # every drive a batch of its own
        ingest("parquet", [folder], tmp_path / "alone.duckdb")

    def stored(name: str) -> dict[str, list[tuple]]:
        with duckdb.connect(str(tmp_path / f"{name}.duckdb"), read_only=True) as con:
            return {t: con.sql(f"select * from {t} order by all").fetchall()
                    for t in ("drive_inputs", "tracks", "track_lanes")}

    batch = stored("batch")
    assert batch == stored("drive_by_drive")
    assert batch == stored("alone")
    where = folder / "tracks.parquet"
    outcome = {r[0]: (r[8], r[9]) for r in batch["drive_inputs"]}
    assert outcome["good"] == ("ingested", None)
    assert outcome["unknown_kind"] == ("rejected", (
        f"{where}: column 'kind' has unknown value(s) 'car'.\n\nHint: kinds are the spec's evaluation_object_kind "
        "values: object, person, cyclist, vehicle, truck, trailer, fod, animal, sign, bus, motorcycle, "
        "emergency_vehicle, stationary_vehicle."))
    assert outcome["millimetres"] == ("rejected", (
        f"{where}: drive 'millimetres': actors move at a median 10,000 m/s between samples. Fix: write x_m and y_m "
        "in metres (millimetres divided by 1000) and t_s in seconds."))
    assert outcome["every_row_bad"] == ("rejected", (
        f"{where}: drive 'every_row_bad' has no usable track rows (102 row(s) with a NULL, NaN or infinite t_s, x_m "
        "or y_m dropped)."))
    assert outcome["duplicates"][0] == "ingested" and outcome["duplicates"][1].startswith("3 exact duplicate row(s)")
    assert sorted(d for d, (status, _) in outcome.items() if status == "rejected") == sorted([
        "unknown_kind", "degrees", "milliseconds", "millimetres", "every_row_bad", "two_egos", "bad_period",
        "long_period", "listed_only", *([] if frame else ["contradicted_period"])])
    if frame:
        assert outcome["same_time"] == ("ingested", ("2 row(s) giving one actor different values at the same t_s "
                                                     "dropped (e.g. actor_id 'ego' at t_s = 2.9)"))


def test_a_median_speed_at_the_limit_is_decided_by_the_drive_s_own_median():
    """A drive whose median speed between samples is within rounding of the limit: alone or in a batch, the
    decision is that of the median of its own speeds."""
    t = np.arange(11) * 0.1
    rows = actor("a", t, t * ingestion.MAX_MEDIAN_SPEED_MPS, Y1, drive_id="edge").with_columns(
        frame=pl.int_range(11, dtype=pl.Int64), heading_rad=pl.lit(None, pl.Float64),
        speed_mps=pl.lit(None, pl.Float64), accel_mps2=pl.lit(None, pl.Float64)
    ).select(ingestion.schema.TRACKS.column_names)
    other = ingestion.DriveData("other", "parquet", "o.parquet", 0.1, scene("other"))
    for upper in (1.0, 1 + 2e-16, 1 - 2e-16):  # the limit a hair above, at and below the median
        drive = ingestion.DriveData("edge", "parquet", "edge.parquet", 0.1, rows.with_columns(pl.col("x_m") * upper))
        x, y, t = (drive.tracks[c] for c in ("x_m", "y_m", "t_s"))
        too_fast = ((x.diff() ** 2 + y.diff() ** 2).sqrt() / t.diff()).drop_nulls().median() > \
            ingestion.MAX_MEDIAN_SPEED_MPS
        for got in (ingestion.clean_batch([drive])[0], ingestion.clean_batch([other, drive, other])[1]):
            assert isinstance(got, InputError) == too_fast


def test_drives_in_runs_are_sliced_and_interleaved_ones_are_not():
    """``parquet.by_drive``: one run per drive in the order given gives each drive's rows; rows of a drive in two
    runs, or runs in another order, give None (the reader then splits by value)."""
    rows = pl.concat([scene("a"), scene("b"), scene("c")])
    sizes = rows.group_by("drive_id", maintain_order=True).len()
    runs = parquet.by_drive(rows, sizes)
    assert list(runs) == ["a", "b", "c"]
    for drive_id, part in runs.items():
        assert part.equals(rows.filter(pl.col("drive_id") == drive_id))
    split = pl.concat([scene("a").head(5), scene("b"), scene("a").slice(5), scene("c")])
    assert parquet.by_drive(split, split.group_by("drive_id", maintain_order=True).len()) is None
    assert parquet.by_drive(rows, sizes.reverse()) is None


def test_ingest_stores_the_same_rows_whatever_the_order_of_the_file(tmp_path):
    """A file as logs come (drive after drive, each in (actor, frame) order) and the same rows shuffled across
    drives give the same tracks and track_lanes."""
    ordered = pl.concat([scene(f"d{i}") for i in range(4)])
    periods = {f"d{i}": 0.1 for i in range(4)}
    files = {"ordered": ordered, "shuffled": ordered.sample(fraction=1.0, shuffle=True, seed=3)}
    stored = {}
    for name, tracks in files.items():
        db = tmp_path / f"{name}.duckdb"
        ingest("parquet", [write(tmp_path / name, tracks, periods)], db)
        with duckdb.connect(str(db), read_only=True) as con:
            stored[name] = {t: con.sql(f"select * from {t} order by all").pl() for t in ("tracks", "track_lanes")}
    assert stored["ordered"]["track_lanes"].height > 0
    for table in ("tracks", "track_lanes"):
        assert stored["ordered"][table].equals(stored["shuffled"][table])


def test_the_kinematics_parts_cut_only_where_the_track_changes():
    track_no = np.array([0, 0, 0, 1, 1, 2, 2, 2, 2, 3])
    assert ingestion.kinematics_parts(track_no, 2) == [(0, 5), (5, 10)]
    assert ingestion.kinematics_parts(track_no, 3) == [(0, 3), (3, 9), (9, 10)]
    assert ingestion.kinematics_parts(np.zeros(10, dtype=np.int64), 4) == [(0, 10)]  # one track: one part
    assert ingestion.kinematics_parts(np.arange(4), 8) == [(0, 1), (1, 2), (2, 3), (3, 4)]
    assert ingestion.kinematics_parts(np.array([], dtype=np.int64), 2) == [(0, 0)]


@pytest.mark.parametrize("parts", [2, 3, 7])
def test_the_kinematics_in_parts_give_what_the_whole_batch_gives(tmp_path, monkeypatch, parts):
    """staging/tracks.sql runs on a part of the batch per core (``_staged``), cut where a track changes: the stored
    tracks are those of the batch in one part. Each actor "a" stands still before it moves (its heading comes from
    rows after it) and each "b" is one sample long, so a cut inside a track would change them."""
    t = times(30)
    standing = np.where(t < 1.0, 50.0, 50.0 + 8 * (t - 1.0))
    tracks = pl.concat([pl.concat([actor("ego", t, 100 + 10 * t, Y1, is_ego=True, drive_id=f"d{i}"),
                                   actor("a", t, standing, Y1 + 0.1 * i, drive_id=f"d{i}"),
                                   actor("b", t[:1], np.array([20.0]), Y1, drive_id=f"d{i}")]) for i in range(5)])
    folder = write(tmp_path / "in", tracks, {f"d{i}": 0.1 for i in range(5)})
    stored = {}
    for n in (1, parts):
        monkeypatch.setattr(ingestion, "WORKERS", n)
        db = tmp_path / f"{n}.duckdb"
        ingest("parquet", [folder], db)
        with duckdb.connect(str(db), read_only=True) as con:
            stored[n] = con.sql("select * from tracks order by all").pl()
    assert stored[1].height == 5 * (2 * len(t) + 1) and stored[1]["heading_rad"].null_count() == 0
    assert stored[1].equals(stored[parts])


def test_a_map_is_written_once_per_run_and_replaced_by_the_next_run(tmp_path, monkeypatch):
    """Drives of one map in many batches store each lane once, as one batch does; a later run that reads the map
    with a lane changed replaces it."""
    tracks = pl.concat([scene(f"d{i}") for i in range(4)])
    folder = write(tmp_path / "in", tracks, {f"d{i}": 0.1 for i in range(4)})

    def lanes(db: Path) -> list[tuple]:
        with duckdb.connect(str(db), read_only=True) as con:
            return con.sql("select map_id, lane_id, polygon_wkt from lanes order by all").fetchall()
    ingest("parquet", [folder], tmp_path / "one.duckdb")
    monkeypatch.setattr(ingestion, "BATCH_ROWS", 1)  # every drive a batch of its own
    ingest("parquet", [folder], tmp_path / "many.duckdb")
    assert lanes(tmp_path / "many.duckdb") == lanes(tmp_path / "one.duckdb")
    assert len(lanes(tmp_path / "many.duckdb")) == len(TWO_LANES)

    moved = pl.DataFrame(TWO_LANES).with_columns(
        polygon_wkt=pl.when(pl.col("lane_id") == "L1").then(pl.lit("POLYGON ((0 0, 500 0, 500 3.5, 0 3.5, 0 0))"))
        .otherwise(pl.col("polygon_wkt")))
    moved.write_parquet(folder / "lanes.parquet")
    ingest("parquet", [folder], tmp_path / "many.duckdb")
    again = lanes(tmp_path / "many.duckdb")
    assert len(again) == len(TWO_LANES)
    assert ("road", "L1", "POLYGON ((0 0, 500 0, 500 3.5, 0 3.5, 0 0))") in again
    # in one run, a second folder with the same map changed: the map as the later folder gives it
    first = write(tmp_path / "first", pl.concat([scene(f"e{i}") for i in range(2)]), {"e0": 0.1, "e1": 0.1})
    ingest("parquet", [first, folder], tmp_path / "two.duckdb")
    assert lanes(tmp_path / "two.duckdb") == again
