"""The scaling benchmark on tiny sizes: stages, fresh-process runs, growth exponents and the table."""

from __future__ import annotations

import pytest

from torch4dtree.bench import scale
from torch4dtree.cli import main


def test_growth_exponent_is_the_log_log_slope():
    assert scale.growth_exponent([10, 20, 40], [3.0, 6.0, 12.0]) == pytest.approx(1.0)
    assert scale.growth_exponent([10, 20], [1.0, 4.0]) == pytest.approx(2.0)
    assert scale.growth_exponent([10], [1.0]) is None
    assert scale.growth_exponent([10, 20], [0.0, 1.0]) is None  # a zero cannot be logged: one usable point


def test_stages_in_process(tmp_path):
    root = scale.write_dataset(tmp_path / "d", plants=3, frames=2, T=8)
    for stage in ("read", "fit_organs", "pairs"):
        r = scale.run_stage(stage, root, T=8)
        assert r["plants"] == 3 and r["frames"] == 6 and r["seconds"] > 0
        assert r["peak_mb"] >= r["base_mb"] > 0 and r["cpu_seconds"] >= 0
    assert scale.run_stage("pairs", root, T=8)["pairs"] == 3
    with pytest.raises(ValueError, match="unknown stage"):
        scale.run_stage("nope", root)


def test_paper_fit_stage_reports_its_layout(tmp_path):
    root = scale.write_dataset(tmp_path / "d", plants=3, frames=2, T=8)
    r = scale.run_stage("fit_paper", root, T=8)
    assert r["slots"] >= 1 and r["dropped_share"] == 0.0 and r["cpu_seconds"] > 0
    assert {"within_sequence", "cross_sequence", "tree_space", "forecast_calibration"} <= set(r["parts"])


def test_benchmark_in_fresh_processes_and_table(tmp_path, capsys, monkeypatch):
    r = scale.benchmark_scale(sizes=[2, 3], frames=2, T=8, workers=[1, 2], stages=["pairs"], keep=tmp_path)
    assert [(x["stage"], x["size"]) for x in r["rows"]] == [("pairs_w1", 2), ("pairs_w2", 2), ("pairs_w1", 3),
                                                            ("pairs_w2", 3)]
    assert set(r["exponents"]) == {"pairs_w1", "pairs_w2"} and set(r["speedup"]) == {2, 3}
    table = scale.format_table(r)
    assert "pairs_w2" in table and "exponent" in table and "speed-up" in table
    seen = []
    monkeypatch.setattr(scale, "benchmark_scale", lambda sizes, log: seen.append(sizes) or r)
    assert main(["benchmark", "scale", "--sizes", "2", "3"]) == 0
    assert seen == [[2, 3]] and "speed-up" in capsys.readouterr().out


def test_cli_rejects_sizes_elsewhere():
    from torch4dtree.cli.options import UsageError

    try:
        code = main(["benchmark", "curves", "--sizes", "3"])
    except (UsageError, SystemExit) as err:
        code = getattr(err, "code", 2)
    assert code != 0
