"""The degree of sensor redundancy (MoM3 §3): the paper's own examples, and every
machine's sensor sets through pkm-analyze."""

import json

import pytest

from pkm_kinematics.analysis import degree_of_sensor_redundancy, measurement_verdict, sensor_redundancy
from pkm_kinematics.cli import main


@pytest.mark.parametrize("c, m, o, d, expected", [
    (1, 1, 1, 1, 0),      # §3.2.1: a solid on a prismatic joint, one measure, perfect case
    (1, 2, 1, 1, -1),     # ... with parasitic motion along y (imperfect): under-measured
    (4, 3, 3, 4, 0),      # §3.2.2 Fig. 6: kinematic redundancy, 4 actuated joints measured
    (4, 3, 3, 3, 1),      # §3.2.3 Fig. 7: actuation redundancy, over-measured
    (6, 6, 3, 3, 0),      # §4.2: MoM3's Gough platform, C = 6, M = 6: iso-measured
])
def test_the_papers_examples(c, m, o, d, expected):
    assert degree_of_sensor_redundancy(c, m, o, d) == expected


def test_verdicts_and_bad_input():
    assert [measurement_verdict(v) for v in (-1, 0, 2)] == ["under-measured", "iso-measured", "over-measured"]
    with pytest.raises(ValueError, match="dosr: C must be an integer >= 0, got -1"):
        degree_of_sensor_redundancy(-1, 3, 3, 3)
    with pytest.raises(ValueError, match="1 <= O <= M <= 6"):
        degree_of_sensor_redundancy(3, 2, 3, 3)


def test_machines_sensor_sets():
    archi = {e.sensors: e for e in sensor_redundancy(4, True)}
    assert (archi["encoders"].dosr_perfect, archi["encoders"].dosr_imperfect) == (1, -2)
    assert archi["gough struts"].dosr_imperfect == 0
    assert [e.sensors for e in sensor_redundancy(3, False)] == ["encoders"]


def test_pkm_analyze_dosr_lists_every_machine(capsys):
    assert main(["--json", "dosr"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert set(data) == {"archi", "mom3", "mom3_imperfect", "orthoglide", "sliding_star", "genhexkins",
                         "hexapod8"}
    mom3 = {row["sensors"]: row for row in data["mom3"]}
    assert mom3["encoders"]["dosr_perfect"] == 0 and mom3["gough struts"]["dosr_imperfect"] == 0
    # the hexapods: D = O = M = 6; six struts iso-measure the platform, eight over-measure it
    assert [(r["sensors"], r["dosr_perfect"], r["dosr_imperfect"]) for r in data["genhexkins"]] == \
        [("encoders", 0, 0)]
    # hexapod8's eight struts over-measure by 2; its Gough metrology's six iso-measure;
    # both together: 14 sensors for 6 DOF
    assert [(r["sensors"], r["dosr_perfect"], r["dosr_imperfect"]) for r in data["hexapod8"]] == \
        [("encoders", 2, 2), ("gough struts", 0, 0), ("encoders + gough struts", 8, 8)]
    assert main(["dosr", "--machine", "nosuch"]) == 2
    assert "unknown machine 'nosuch'" in capsys.readouterr().err
