"""`elasticoop montecarlo sensitivity` as a user runs it: the `[sensitivity]`
table's problems named, and the shipped study's table run at small size, analysed
again from its store, and extended with more base points."""

import json

import numpy as np
import pytest

from elasticoop import montecarlo as mc
from elasticoop._cli import main
from elasticoop._examples import example_studies

SHIPPED = example_studies()["beam_lift"]


def _small_study(tmp_path, sensitivity=None):
    """The shipped study on a 0.3 s span with 7 output times (its scenario named as
    a shipped example), its `[sensitivity]` table replaced by `sensitivity`."""
    text = SHIPPED.read_text(encoding="utf-8")
    text = text.replace('scenario = "beam_lift.toml"', 'scenario = "beam_lift"')
    text = text.replace("[time]\nsamples = 61", "[time]\nstop = 0.3\nsamples = 7")
    if sensitivity is not None:
        text = text[: text.index("[sensitivity]")] + sensitivity
    path = tmp_path / "small.study.toml"
    path.write_text(text, encoding="utf-8")
    return path


@pytest.mark.parametrize(
    "table, message",
    [
        ("[sensitivity]\nsamples = 100\n", "samples = 100: the sobol design takes a"),
        ('[sensitivity]\noutputs = ["force"]\n', "no output named 'force'"),
        ('[sensitivity]\nmethod = "fast"\n', "method"),
        ('[sensitivity]\nmethod = "morris"\nsecond_order = true\n', "needs method"),
    ],
)
def test_a_bad_sensitivity_table_is_named(tmp_path, capsys, table, message):
    study = _small_study(tmp_path, table)
    code = main(["montecarlo", "sensitivity", str(study), "-o", str(tmp_path / "s")])
    err = capsys.readouterr().err
    assert code == 2 and "[sensitivity]" in err and message in err, err
    assert "Traceback" not in err


def test_a_store_of_another_design_is_refused_with_the_way_out(tmp_path, capsys):
    assert main(["montecarlo", "sensitivity", str(tmp_path)]) == 2
    assert "not a study store" in capsys.readouterr().err


@pytest.mark.slow  # ~2 min on 2 shared cores: compiles the beam lift, derivatives
def test_sensitivity_runs_analyses_again_and_extends(tmp_path, capsys):
    study = _small_study(tmp_path)
    store = tmp_path / "sobol"
    argv = ["montecarlo", "sensitivity", str(study), "-o", str(store)]
    assert main([*argv, "--samples", "2"]) == 0, capsys.readouterr().err
    out = capsys.readouterr().out
    assert "Sobol' indices from 2 base points (54 runs)" in out
    assert "stiffness[beam-left, x]" in out and "DGSM bound" in out
    folder = store / "sensitivity"
    written = {p.name for p in folder.iterdir()}
    assert {"indices.nc", "indices.json", "heatmap_pose.png"} <= written
    assert {"sobol_peak_force.png", "convergence_peak_force.png"} <= written
    # the JSON holds the indices the Python API gives on the store
    report = json.loads((folder / "indices.json").read_text())
    ds = mc.open_study(store)
    ind = mc.sobol_indices(ds, ["peak_force"], bootstrap=1000)
    stored = report["indices"]["variables"]["ST_peak_force"]["data"]
    np.testing.assert_allclose(np.asarray(stored, float), ind["ST_peak_force"].values)
    assert report["indices"]["coords"]["factor"][0] == "stiffness[beam-left, x]"
    # the store alone, analysed again
    assert main(["montecarlo", "sensitivity", str(store), "-q"]) == 0
    # more base points: the stored samples are kept, the new ones run (without
    # the derivatives this time: the table is not part of the stored study)
    study.write_text(study.read_text().replace("dgsm_samples = 16", "dgsm_samples = 0"))
    assert main([*argv, "--samples", "4", "-q"]) == 0, capsys.readouterr().err
    larger = mc.open_study(store)
    assert larger.sizes["sample"] == 4 * 27
    for name in ("peak_force", "stiffness", "status"):
        np.testing.assert_array_equal(larger[name].values[:54], ds[name].values)
