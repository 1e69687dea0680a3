"""pkm-gallery: each paper experiment runs from its scenario files and its checks pass
(the same numbers docs/results.md shows); results.md says which check failed and the
command exits 1 then."""


import pytest

from pkm_gallery import gallery
from pkm_gallery.experiments import EXPERIMENTS
from pkm_gallery.framework import Bench, Check, Experiment, Outcome
from pkm_gallery.gallery import markdown_table, results_markdown
from pkm_kinematics.config import config_dir

pytestmark = pytest.mark.ros


def test_every_experiment_names_a_known_paper_and_shipped_scenarios():
    for exp in EXPERIMENTS.values():
        assert exp.paper in gallery.PAPERS
        for scenario in exp.scenarios:
            assert (config_dir() / "scenarios" / f"{scenario}.yaml").is_file(), (exp.name, scenario)
    with pytest.raises(ValueError, match="paper: must be one of"):
        Experiment("x", "x", "Hexaglide", "§1", (), lambda bench: Outcome())


def test_results_md_gives_each_claim_ours_and_a_verdict_and_flags_a_failure():
    good = Outcome([Check("claim a", "1 N", True)], table=[["k", "v"], ["a|b", "2"]], figures=["a.png"])
    bad = Outcome([Check("claim b", "3 N", True), Check("claim c", "9 N (limit 5 N)", False)])
    e1 = Experiment("e1", "first", "ARCHI", "§3.3", ("archi_fig10",), None)
    e2 = Experiment("e2", "second", "MoM3", "Table 2", ("mom3_square",), None)
    text = results_markdown([(e1, good, 1.0), (e2, bad, 2.0)], pending=[("e3", "MoM3 Table 3", "no frame model")])
    assert "| [e1](#e1) | ARCHI §3.3 | 1 / 1 | reproduced |" in text
    assert "| [e2](#e2) | MoM3 Table 2 | 1 / 2 | NOT reproduced |" in text
    assert "| claim c | 9 N (limit 5 N) | FAIL |" in text
    assert "- `e3` (MoM3 Table 3): no frame model" in text
    assert "| a\\|b | 2 |" in text and "![a.png](figures/a.png)" in text
    assert not bad.passed and good.passed
    assert markdown_table([]) == ""


def test_an_unknown_experiment_is_refused_naming_the_known_ones(capsys):
    assert gallery.main(["archi_fig99"]) == 2
    assert "unknown experiment(s) ['archi_fig99']; known: ['archi_fig10'" in capsys.readouterr().err


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(EXPERIMENTS))
def test_the_experiment_reproduces_the_paper(tmp_path, name):
    outcome = EXPERIMENTS[name].run(Bench(tmp_path / "work", tmp_path / "figures"))
    failed = [f"{c.claim}: {c.measured}" for c in outcome.checks if not c.passed]
    assert outcome.checks and not failed, failed
    for figure in outcome.figures:
        assert (tmp_path / "figures" / figure).stat().st_size > 10_000, figure
