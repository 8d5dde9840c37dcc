import json

import pytest
from conftest import pheno4d

from torch4dtree.cli import main


def run_json(capsys, *argv):
    assert main([*argv, "--json"]) == 0
    return json.loads(capsys.readouterr().out)


def test_info_on_a_sequence_folder(capsys):
    out = run_json(capsys, "info", str(pheno4d("swc", "Tomato_3")), "--T", "16")
    assert out["frames"] == 11 and len(out["times"]) == 11 and len(out["height"]) == 11
    b = out["branches"]
    assert b[-1] > 10 * b[0] and all(later >= 0.9 * earlier for earlier, later in zip(b, b[1:]))
    assert out["height"][-1] > 2 * out["height"][0]


def test_info_on_mat_sequence_file_and_dataset(capsys):
    seq = run_json(capsys, "info", str(pheno4d("mat", "tom_3_seq")), "--T", "16")
    assert seq["frames"] == 10 and seq["height"][-1] > seq["height"][0]
    one = run_json(capsys, "info", str(pheno4d("mat", "tom_3_seq", "03_25.mat")), "--T", "16")
    assert one["branches"] == seq["branches"][-1] and one["height"] == seq["height"][-1]
    alt = run_json(capsys, "info", str(pheno4d("mat", "maize01_seq_alt")), "--T", "16")
    assert alt["frames"] == 4 and len(alt["skipped"]) == 3


def test_info_human_output_and_errors(capsys, tmp_path):
    assert main(["info", str(pheno4d("mat", "maize02_seq"))]) == 0
    text = capsys.readouterr().out
    assert "maize02_seq: 6 frames" in text
    bad = tmp_path / "bad.swc"
    bad.write_text("1 0 0 0 0 1 -1\n2 0 0 0 1 1 5\n")
    assert main(["info", str(bad)]) == 2
    assert "bad.swc:2: node 2 has parent 5" in capsys.readouterr().err
    assert main(["info", str(tmp_path / "missing")]) == 2


def test_info_on_a_dataset_of_swc_plants(capsys):
    out = run_json(capsys, "info", str(pheno4d("swc")), "--T", "8", "--repair")
    assert len(out["sequences"]) == 9
    assert all(s["frames"] == len(s["height"]) for s in out["sequences"])


@pytest.mark.parametrize("kind", ["tomato", "maize"])
def test_synth_then_info(capsys, tmp_path, kind):
    out_dir = tmp_path / kind
    assert main(["synth", "--kind", kind, "--plants", "2", "--seed", "3", "--frames", "5", "--out", str(out_dir)]) == 0
    capsys.readouterr()
    out = run_json(capsys, "info", str(out_dir), "--T", "16")
    assert len(out["sequences"]) == 2
    for s in out["sequences"]:
        assert s["frames"] == 5 and s["height"][-1] > s["height"][0]
    # a second run refuses to overwrite the dataset
    assert main(["synth", "--kind", kind, "--plants", "2", "--seed", "3", "--frames", "5", "--out", str(out_dir)]) == 2
