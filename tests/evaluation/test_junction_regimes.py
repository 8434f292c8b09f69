"""The junction regimes of issue 36 (logiq_sql/evaluation/simulate.py): the network and demand files they write,
read back as XML, and their bad values. No SUMO run (the campaign runs them)."""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET

import pytest

from logiq_sql.core.errors import LogiqError
from logiq_sql.evaluation.simulate import Regime, _junction, _junction_routes, command_options


def test_skew_cycle_speed_and_backed_up_exits_in_the_network(tmp_path):
    regime = Regime(skew_deg=20, cycle_s=60, speed_kmh=40, exit_backup=True)
    options = _junction(tmp_path, regime)
    assert options[options.index("--tls.cycle.time") + 1] == "60"
    nodes = {n.get("id"): (float(n.get("x")), float(n.get("y")))
             for n in ET.parse(tmp_path / "network.nod.xml").getroot()}
    # the north arm 20 degrees clockwise of north, the east arm due east: the roads cross at 70 degrees
    assert math.degrees(math.atan2(nodes["N"][0], nodes["N"][1])) == pytest.approx(20, abs=0.01)
    assert nodes["E"] == (300.0, 0.0) and math.hypot(*nodes["Nx"]) == pytest.approx(50, abs=0.01)
    edges = {e.get("id"): e for e in ET.parse(tmp_path / "network.edg.xml").getroot()}
    assert float(edges["N2C"].get("speed")) == pytest.approx(40 / 3.6, abs=0.01)
    assert edges["Nx2N"].get("numLanes") == "1" and edges["C2N"].get("to") == "Nx"
    flows = [f for f in ET.fromstring("<r>" + "".join(_junction_routes(60, regime)) + "</r>").iter("flow")]
    assert {f.get("to") for f in flows} == {"Nx2N", "Ex2E", "Sx2S", "Wx2W"}
    assert "--skew 20 --cycle 60 --speed 40 --exit-backup" in command_options("junction", 8, 1, regime)
    assert command_options("junction", 8, 1, Regime()).endswith("--approach-lanes 3")  # defaults: as before


def test_motorcycles_among_the_left_turners():
    routes = ET.fromstring("<r>" + "".join(_junction_routes(60, Regime(motorcycle_share=0.15))) + "</r>")
    motos = [t for t in routes.iter("vType") if t.get("vClass") == "motorcycle"]
    assert {t.get("id") for t in motos} == {"motorcycle", "motorcycle_left"}
    assert all(float(t.get("probability")) == pytest.approx(0.15) for t in motos)


@pytest.mark.parametrize("bad, message", [
    (dict(skew_deg=50), "--skew 50"), (dict(cycle_s=20), "--cycle 20"), (dict(speed_kmh=100), "--speed 100"),
    (dict(motorcycle_share=0.5, truck_share=0.3, bus_share=0.2), "--motorcycle-share 0.5"),
])
def test_bad_regimes_say_what_to_give(bad, message):
    with pytest.raises(LogiqError, match=message):
        Regime(**bad)
