"""``torch4dtree benchmark all --quick --json``: every section, one JSON object, the ratio table."""

from __future__ import annotations

import json

import pytest
from conftest import PHENO4D

from torch4dtree.cli import main

SECTIONS = ("curves", "trees", "4d", "model")


def _run(capsys, *extra: str) -> dict:
    assert main(["benchmark", "all", "--quick", "--json", *extra]) == 0
    return json.loads(capsys.readouterr().out)  # stdout holds the JSON alone (progress goes to stderr)


def _check_ratios(result: dict) -> None:
    assert result["ratios"]
    for name, r in result["ratios"].items():
        assert set(r) == {"ours_s", "reference_s", "reference", "ratio", "what"}, name
        if r["ours_s"] is not None and r["reference_s"] is not None:
            assert r["ratio"] == pytest.approx(r["reference_s"] / r["ours_s"]), name
        else:
            assert r["ratio"] is None, name


@pytest.mark.skipif(not (PHENO4D / "swc").is_dir(), reason="needs the Pheno4D skeletons")
def test_benchmark_all_quick_runs_every_section(capsys):
    result = _run(capsys, "--data", str(PHENO4D))
    assert result["quick"] is True and result["notes"] == []
    for name in SECTIONS:
        assert "skipped" not in result[name], name
        assert result["seconds"][name] > 0
    _check_ratios(result)
    ratios = result["ratios"]
    # the paper's references are always there; fdasrsf only where it is importable
    for name in ("tree_pair_vs_paper", "4d_pair_tomato_vs_paper", "4d_pair_maize_vs_paper", "mean_4d_vs_paper",
                 "sample_one_vs_paper", "temporal_one_pair_vs_paper"):
        assert ratios[name]["ratio"] > 0, name
    assert (ratios["curve_pair_vs_fdasrsf"]["ratio"] is None) == (not result["curves"]["fdasrsf_available"])
    assert result["trees"]["pairs"] == 4 and result["model"]["modes"] >= 1


def test_benchmark_all_without_data_skips_the_pheno4d_parts(capsys, tmp_path):
    result = _run(capsys, "--data", str(tmp_path))
    assert set(SECTIONS) <= set(result)
    assert "skipped" in result["trees"] and "skipped" in result["4d"]
    assert "skipped" not in result["curves"] and "skipped" not in result["model"]
    assert any(n.startswith("trees") for n in result["notes"]) and any(n.startswith("4d") for n in result["notes"])
    _check_ratios(result)
    assert result["ratios"]["tree_pair_vs_paper"]["ratio"] is None
    assert result["ratios"]["sample_batched_vs_paper"]["ratio"] > 0


def test_quick_is_for_all_only(capsys):
    assert main(["benchmark", "curves", "--quick"]) == 2
