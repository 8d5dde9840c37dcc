"""``torch4dtree evaluate``: the report's structure, that every registration it reports lowered the distance, that
the generative metrics are finite and in range, data discovery and the command's errors (issue 14)."""

from __future__ import annotations

import contextlib
import io
import json
import math
from pathlib import Path

import pytest
from conftest import pheno4d

from torch4dtree.cli.main import main
from torch4dtree.evaluate import EvalSettings, evaluate, load_eval_data, sources_of
from torch4dtree.io.dataset import DatasetError

EPS = ("0.1", "0.05", "0.02", "0.01")


@pytest.fixture(scope="module")
def dataset(synthetic_folder) -> Path:
    return synthetic_folder(4, 5, 4)


@pytest.fixture(scope="module")
def report(dataset: Path, tmp_path_factory) -> tuple[dict, Path]:
    """The whole evaluation, quick, through the command line (--json and --out), figures included."""
    out = tmp_path_factory.mktemp("report") / "r"
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        code = main(["evaluate", str(dataset), "--quick", "--T", "16", "--T-cycle", "24", "--n-t", "8", "--json",
                     "--out", str(out), "--quiet"])
    assert code == 0
    return json.loads(buf.getvalue()), out


def test_report_files_and_json_contract(report: tuple[dict, Path]) -> None:
    rep, out = report
    for key in ("table1", "table2", "table3", "generative", "synthetic", "robustness", "timings"):
        assert key in rep, key
    assert json.loads((out / "report.json").read_text())["table2"] == rep["table2"]
    cc = rep["table2"]["cycle_consistency"]
    assert set(cc) == set(EPS)
    for eps in EPS:
        for stat in ("mean", "median", "std"):
            assert 0.0 <= cc[eps][stat] <= 1.0  # fractions, not percentages
    # a looser threshold never fails more points
    means = [cc[e]["mean"] for e in EPS]
    assert means == sorted(means)
    assert all(v["seconds"] >= 0 for v in rep["timings"].values()) and rep["timings"]["total"]["seconds"] > 0
    md = (out / "report.md").read_text()
    for title in ("Table 1", "Table 2", "Table 3", "Generative model", "Synthetic ground truth", "Robustness"):
        assert title in md, title
    assert "0.94 %" in md  # the paper's figure beside ours
    figures = {Path(f).name for f in rep["figures"]}
    assert {"registration.png", "geodesic4d.png", "mean.png", "robustness.png"} <= figures
    assert all((out / f).stat().st_size > 1000 for f in figures)


def test_every_registration_lowered_its_distance(report: tuple[dict, Path]) -> None:
    rep = report[0]
    t1 = rep["table1"]
    for kinds in t1["trees3d"].values():
        for r in kinds.values():
            assert r["pairs"] > 0 and r["raised"] == 0 and r["after"]["mean"] <= r["before"]["mean"]
    for r in t1["plants4d"].values():
        assert r["pairs"] > 0
        for row in r["rows"]:
            assert row["after"] <= row["before"] + 1e-9
    for kind in rep["table3"]["kinds"].values():
        for row in kind["pairs"]["rows"]:
            assert row["after"] <= row["before"] + 1e-9
        assert kind["pairs"]["raised"] == 0


def test_generative_metrics_are_finite_and_in_range(report: tuple[dict, Path]) -> None:
    kinds = report[0]["generative"]["kinds"]
    assert kinds
    for k in kinds.values():
        for gen, m in k["generators"].items():
            assert math.isfinite(m["mmd"]["mean"]) and m["mmd"]["mean"] >= 0, gen
            for key in ("cov", "nna", "nna_samples", "nna_real"):
                assert 0.0 <= m[key]["min"] <= m[key]["max"] <= 1.0, (gen, key)
        assert k["sanity"] == {"mmd": 0.0, "cov": 1.0, "nna": 0.0}


def test_existing_report_is_not_overwritten(report: tuple[dict, Path], dataset: Path, capsys) -> None:
    _, out = report
    before = (out / "report.json").read_text()
    with pytest.raises(FileExistsError):
        evaluate(dataset, out, EvalSettings(quick=True, figures=False), sections=("spatial",))
    with pytest.raises(ValueError, match="unknown sections"):
        evaluate(dataset, None, EvalSettings(quick=True), sections=("tables",))
    assert main(["evaluate", str(dataset), "--out", str(out), "--quick", "--sections", "spatial"]) == 2
    assert "--overwrite" in capsys.readouterr().err
    assert (out / "report.json").read_text() == before


def test_bad_input_fails_clearly(dataset: Path, tmp_path, capsys) -> None:
    assert main(["evaluate", str(dataset), "--sections", "spatial,tables"]) == 2
    assert "tables" in capsys.readouterr().err
    (tmp_path / "empty").mkdir()
    assert main(["evaluate", str(tmp_path / "empty")]) == 2
    assert "neither a Pheno4D-style folder" in capsys.readouterr().err
    with pytest.raises(DatasetError, match="not a folder"):
        sources_of(tmp_path / "missing")


def test_pheno4d_discovery() -> None:
    root = pheno4d()
    assert sources_of(root) == ["mat", "swc"]
    mat = load_eval_data(root, "mat", T=16)
    assert mat.kinds == ["tomato", "maize"]
    names = [p.name for p in mat.plants]
    assert not any(n.endswith(("_alt", "_altered")) for n in names)  # altered copies ride along, not as plants
    tom1 = next(p for p in mat.plants if p.name == "tom_1_seq")
    assert tom1.altered is not None and len(tom1.altered) < len(tom1.sequence)
    assert len(tom1.files) == len(tom1.sequence) and all(f.is_file() for f in tom1.files)


def test_any_dataset_folder_is_evaluated_as_one_kind(dataset: Path, tmp_path) -> None:
    """A dataset folder of the kind `fit` reads (no dataset.json, no mat/ or swc/) is source `folder`, one kind."""
    import shutil

    generic = tmp_path / "plants"
    shutil.copytree(dataset, generic)
    (generic / "dataset.json").unlink()
    assert sources_of(generic) == ["folder"]
    data = load_eval_data(generic, "folder", T=16)
    assert data.kinds == ["plant"] and len(data.plants) == 4 and not data.has_truth
    rep = evaluate(generic, None, EvalSettings(T=16, T_cycle=16, n_t=8, quick=True, figures=False),
                   sections=("spatial", "truth"))
    assert rep["table1"]["source_4d"] == "folder" and "synthetic" not in rep
    assert rep["table1"]["plants4d"]["plant"]["pairs"] > 0
