"""The pipeline's outputs on the bundled drives equal the golden files (tests/golden.py says what they hold and
how to regenerate them after a deliberate change of meaning)."""

from __future__ import annotations

import polars as pl
import pytest

from tests import golden


@pytest.mark.parametrize("setting", list(golden.SETTINGS))
def test_outputs_equal_the_golden_files(setting, tmp_path, ingested):
    got = golden.build(setting, tmp_path, ingested)
    assert got["matches"].height > 0  # the comparison below compares something
    assert golden.compare(setting, got) == []


def test_a_changed_result_is_caught(tmp_path):
    """The comparison fails when one KPI moves by more than a rounding error, or one match goes."""
    got = {t: pl.read_parquet(golden.path_of("sumo_junction", t)) for t in golden.TABLES}
    assert golden.compare("sumo_junction", got) == []
    moved = dict(got, kpis=got["kpis"].with_columns(pl.col("pet_between_sut_and_npc_s") * 1.001))
    assert any("kpis" in p for p in golden.compare("sumo_junction", moved))
    fewer = dict(got, matches=got["matches"].slice(1))
    assert any("matches" in p for p in golden.compare("sumo_junction", fewer))
