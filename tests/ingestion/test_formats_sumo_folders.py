"""SUMO run folders are recognised by their .sumocfg or by the files' content, never by a name pattern (issue 20).

The bundled junction run is copied under other names (``net.xml.gz``, ``trace.gz``, ...) and must ingest into the
same tables as the original; a .sumocfg picks the files when the content alone is ambiguous.
"""

from __future__ import annotations

import gzip
import shutil
from pathlib import Path

import duckdb
import polars as pl
import pytest

from logiq_sql import ingest
from logiq_sql.core.errors import InputError
from logiq_sql.ingestion.readers.sumo import file_role, read_sumo, run_files, run_folders

DATA = Path(__file__).parents[1] / "data" / "sumo"
JUNCTION = DATA / "junction_s1"
# original name -> a name no pattern would recognise
RENAMES = {"network.net.xml.gz": "net.xml.gz", "fcd.xml.gz": "trace.gz", "routes.rou.xml": "demand.xml",
           "tls_states.xml.gz": "signals", "lanechange.xml.gz": "lc.xml.gz"}


def _renamed(tmp_path: Path, name: str = "renamed") -> Path:
    run = tmp_path / "runs" / name
    shutil.copytree(JUNCTION, run)
    for old, new in RENAMES.items():
        (run / old).rename(run / new)
    return run


def _tables(db: Path, drive: str) -> dict[str, pl.DataFrame]:
    with duckdb.connect(str(db), read_only=True) as con:
        return {
            "tracks": con.sql(f"select * exclude (drive_id, drive_key) from tracks where drive_id = '{drive}' "
                              "order by actor_id, frame").pl(),
            "lanes": con.sql("select * exclude (map_id) from lanes order by lane_id").pl(),
            "states": con.sql(f"select light_id, frame, state from traffic_light_states where drive_id = '{drive}' "
                              "order by light_id, frame").pl(),
            "map": con.sql(f"select map_id from drive_inputs where drive_id = '{drive}'").pl(),
        }


def test_roles_come_from_the_root_element():
    roles = {f.name: file_role(f) for f in JUNCTION.iterdir()}
    assert roles["network.net.xml.gz"] == "network"
    assert roles["fcd.xml.gz"] == "fcd"
    assert roles["routes.rou.xml"] == "routes"
    assert roles["tls.add.xml"] == "routes"  # an additional file: vTypes may live there
    assert roles["tls_states.xml.gz"] == "tls_states"
    assert roles["lanechange.xml.gz"] == "lanechange"
    assert roles["network.nod.xml"] is None and roles["SOURCE.md"] is None and roles["sumo.log"] is None


def test_a_run_with_any_file_names_ingests_like_the_original(tmp_path, ingested):
    run = _renamed(tmp_path)
    (run / "notes.xml").write_text("<notes><note>not SUMO</note></notes>")  # other XML is ignored
    assert run_folders(tmp_path / "runs") == [run]
    files = run_files(run)
    assert files["network"] == [run / "net.xml.gz"] and files["fcd"] == [run / "trace.gz"]
    assert files["tls_states"] == [run / "signals"]
    renamed_db, original_db = tmp_path / "renamed.duckdb", tmp_path / "original.duckdb"
    assert ingest("sumo", [tmp_path / "runs"], renamed_db).drives == 1
    ingested(original_db, "sumo", [JUNCTION])  # the original run, ingested once per session
    assert ingested.summary("sumo", [JUNCTION]).drives == 1
    got, want = _tables(renamed_db, "renamed"), _tables(original_db, "junction_s1")
    assert got["tracks"].height > 100_000 and got["tracks"].equals(want["tracks"])
    assert got["lanes"].height >= 40 and got["lanes"].equals(want["lanes"])
    assert got["states"].height > 1000 and got["states"].equals(want["states"])
    assert got["map"].equals(want["map"])  # the map id comes from the network's text, not its name


def test_a_sumocfg_names_the_files_to_read(tmp_path):
    run = _renamed(tmp_path)
    # a second, stale FCD output: by content alone the folder is ambiguous
    stale = gzip.decompress((run / "trace.gz").read_bytes()).split(b"</timestep>")[0] + b"</timestep>\n</fcd-export>\n"
    (run / "old_trace.xml").write_bytes(stale)
    with pytest.raises(InputError, match=r"2 FCD files \(old_trace.xml, trace.gz\).*\.sumocfg"):
        list(read_sumo(run))
    (run / "run.sumocfg").write_text(
        '<configuration>\n  <input>\n    <net-file value="net.xml.gz"/>\n    <route-files value="demand.xml"/>\n'
        '    <additional-files value="tls.add.xml"/>\n  </input>\n'
        '  <output>\n    <fcd-output value="trace.gz"/>\n  </output>\n</configuration>\n')
    assert run_files(run)["fcd"] == [run / "trace.gz"]
    (drive,) = read_sumo(run)
    assert drive.tracks.height == next(read_sumo(JUNCTION)).tracks.height
    # the configuration wins over content: naming the stale output reads the stale output
    (run / "run.sumocfg").write_text('<configuration><output><fcd-output value="old_trace.xml"/></output>'
                                     '</configuration>')
    with pytest.raises(InputError, match="fewer than two timesteps"):
        list(read_sumo(run))


def test_a_folder_with_no_network_says_how_networks_are_found(tmp_path):
    run = _renamed(tmp_path)
    (run / "net.xml.gz").unlink()
    with pytest.raises(InputError, match=r"no SUMO network file \(none named by a \.sumocfg, no file whose root "
                                         r"element is <net>\)"):
        list(read_sumo(run))


def test_two_configurations_are_refused(tmp_path):
    run = _renamed(tmp_path)
    for name in ("a.sumocfg", "b.sumocfg"):
        (run / name).write_text('<configuration><input><net-file value="net.xml.gz"/></input></configuration>')
    with pytest.raises(InputError, match=r"2 SUMO configurations \(a.sumocfg, b.sumocfg\)"):
        list(read_sumo(run))


def test_a_small_truncated_gzip_fcd_is_still_found_and_reported_as_truncated(tmp_path):
    run = _renamed(tmp_path)
    head = gzip.compress(gzip.decompress((run / "trace.gz").read_bytes())[:20_000])
    (run / "trace.gz").write_bytes(head[: len(head) // 2])  # a gzip stream cut in its first 10 KB
    assert file_role(run / "trace.gz") == "fcd"
    with pytest.raises(InputError, match=r"trace.gz: cannot be read to the end .* the file is truncated"):
        list(read_sumo(run))


def test_only_sumo_configurations_count_as_configurations(tmp_path):
    netccfg = tmp_path / "build.cfg"
    netccfg.write_text('<configuration><input><sumo-net-file value="a.net.xml"/></input></configuration>')
    sumocfg = tmp_path / "run.cfg"  # not named .sumocfg: its <net-file> option says what it is
    sumocfg.write_text('<!-- <net> in a comment --><configuration><input><net-file value="a.net.xml"/></input>'
                       '</configuration>')
    assert (file_role(netccfg), file_role(sumocfg)) == (None, "config")
