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


# ----------------------------------------------------------------------------- first contact (issue 15)
CYCLE_SWC = "1 0 0 0 0 1 -1\n2 0 0 0 1 1 1\n3 0 0 0 2 1 2\n4 0 0 0 3 1 6\n5 0 0 0 4 1 4\n6 0 0 0 2 1 5\n"
SMALL_SWC = "1 0 0 0 0 1 -1\n2 0 0 0 1 1 1\n3 0 0 0 2 1 2\n4 0 1 0 1.5 1 2\n5 0 2 0 2 1 4\n"


def one_line_error(capsys, command: str) -> str:
    """The stderr of a failed command: exactly one line, prefixed with the command, no traceback."""
    err = capsys.readouterr().err
    lines = err.strip("\n").split("\n")
    assert len(lines) == 1, err
    assert lines[0].startswith(f"torch4dtree {command}: error: ") and "Traceback" not in err, err
    return lines[0]


@pytest.mark.parametrize("argv, message", [
    (["synth", "--plants", "0"], "--plants: must be at least 1, got 0"),
    (["synth", "--plants", "-1"], "--plants: must be at least 1, got -1"),
    (["synth", "--frames", "0"], "--frames: must be at least 2, got 0"),
    (["synth", "--seed", "-3"], "--seed: must be at least 0, got -3"),
    (["benchmark", "curves", "--pairs", "0"], "--pairs: must be at least 1, got 0"),
    (["render", "tree.swc", "--out", "x.png", "--frames", "0"], "--frames: must be at least 1, got 0"),
    (["render", "tree.swc", "--out", "x.gif", "--fps", "0"], "--fps: must be a finite number > 0"),
    (["register", "a.swc", "b.swc", "--steps", "1"], "--steps: must be at least 2, got 1"),
    (["info", "x.swc", "--T", "1.5"], "--T: expected a whole number >= 1, got '1.5'"),
])
def test_bad_numbers_are_one_line_errors_with_exit_code_2(capsys, tmp_path, argv, message):
    argv = [a if not a.endswith((".png", ".gif")) else str(tmp_path / a) for a in argv]
    if argv[0] == "synth":
        argv += ["--out", str(tmp_path / "data")]
    assert main(argv) == 2
    assert message in one_line_error(capsys, argv[0])
    assert not (tmp_path / "data").exists() and not (tmp_path / "x.png").exists()


def test_render_refuses_an_output_in_a_missing_folder(capsys, tmp_path):
    tree = tmp_path / "tree.swc"
    tree.write_text(SMALL_SWC)
    out = tmp_path / "nonexistent_dir" / "x.png"
    assert main(["render", str(tree), "--out", str(out)]) == 2
    assert "nonexistent_dir does not exist" in one_line_error(capsys, "render")
    assert not out.parent.exists()  # no silent mkdir
    assert main(["render", str(tree), "--out", str(tmp_path / "x.txt")]) == 2
    assert "must end in .png" in one_line_error(capsys, "render")


def test_register_names_a_folder_and_a_missing_file(capsys, tmp_path):
    tree = tmp_path / "tree.swc"
    tree.write_text(SMALL_SWC)
    assert main(["register", str(tmp_path), str(tree)]) == 2
    assert f"{tmp_path} is a folder; register takes two tree files" in one_line_error(capsys, "register")
    assert main(["register", str(tree), str(tmp_path / "missing.swc")]) == 2
    assert "missing.swc: no such file" in one_line_error(capsys, "register")
    assert main(["register", str(tree), str(tree), "--out", str(tmp_path / "no" / "such" / "dir")]) == 2
    assert "does not exist (create it first)" in one_line_error(capsys, "register")


def test_write_errors_name_the_target_not_the_temporary_file(capsys, tmp_path):
    tree = tmp_path / "tree.swc"
    tree.write_text(SMALL_SWC)
    out = tmp_path / "pair"
    (out / "reference.swc").mkdir(parents=True)  # a folder where a file is to be written
    assert main(["register", str(tree), str(tree), "--out", str(out), "--overwrite", "--T", "8"]) == 2
    line = one_line_error(capsys, "register")
    assert str(out / "reference.swc") in line and "/.reference.swc." not in line, line
    assert sorted(p.name for p in out.iterdir()) == ["moving_registered.swc", "reference.swc"]  # no temporary left


def test_warnings_are_one_line_without_source(capsys, tmp_path):
    swc = tmp_path / "cycle.swc"
    swc.write_text(CYCLE_SWC)
    assert main(["info", str(swc), "--repair", "--T", "8"]) == 0
    err = capsys.readouterr().err.strip().split("\n")
    assert err == [f"torch4dtree info: warning: {swc}: repaired: joined node 6 to node 3 (distance 0)"] or (
        len(err) == 1 and err[0].startswith("torch4dtree info: warning: ") and "joined node 6" in err[0]), err
    assert main(["info", str(swc), "--T", "8"]) == 2
    assert "--repair" in one_line_error(capsys, "info")


def test_benchmark_trees_explains_where_the_real_data_comes_from(capsys, tmp_path, monkeypatch):
    assert main(["benchmark", "trees", "--data", str(tmp_path / "none")]) == 2
    line = one_line_error(capsys, "benchmark")
    assert f"no Pheno4D skeletons at {tmp_path / 'none' / 'swc'} (--data)" in line
    assert "github.com/Tahmina979/4Dtreeshape_project" in line and "TORCH4DTREE_PHENO4D" in line
    monkeypatch.setenv("TORCH4DTREE_PHENO4D", str(tmp_path / "elsewhere"))
    assert main(["benchmark", "trees"]) == 2
    assert f"{tmp_path / 'elsewhere' / 'swc'} ($TORCH4DTREE_PHENO4D)" in one_line_error(capsys, "benchmark")


def test_version_and_help(capsys):
    import torch4dtree

    assert main(["--version"]) == 0
    assert capsys.readouterr().out.strip() == f"torch4dtree {torch4dtree.__version__}"
    assert main(["--help"]) == 0
    top = capsys.readouterr().out
    assert "``" not in top and "warmup" in top and "Exit codes" in top
    assert main([]) == 2
    err = capsys.readouterr().err
    assert err == "torch4dtree: error: the following arguments are required: COMMAND (see 'torch4dtree --help')\n"


def test_every_option_has_help_with_its_default():
    """Every option of every command explains itself and shows its default (or says there is none)."""
    import argparse

    from torch4dtree.cli import build_parser

    parser = build_parser()
    subparsers = parser._subparsers._group_actions[0].choices
    assert "``" not in (parser.description + parser.epilog)
    for name, sub in subparsers.items():
        assert "``" not in (sub.description or "") + (sub.epilog or ""), name
        for action in sub._actions:
            if isinstance(action, argparse._HelpAction):
                continue
            where = f"{name} {action.option_strings or action.dest}"
            assert action.help and "``" not in action.help, where
            flag = isinstance(action, (argparse._StoreTrueAction, argparse._StoreFalseAction))
            if action.option_strings and not flag and not action.required:
                assert "default" in action.help, where  # "(default: ...)", the built-in one for config flags
            if action.default not in (None, False, True) and not flag:
                assert "%(default)s" in action.help or str(action.default) in action.help, where


def test_help_imports_neither_torch_nor_numba():
    """``torch4dtree --help`` and every ``COMMAND --help`` build their parser without the heavy imports."""
    import subprocess
    import sys

    code = ("import sys, contextlib, io\n"
            "from torch4dtree.cli.main import main, COMMANDS\n"
            "for argv in [['--help'], ['--version']] + [[c, '--help'] for c, _, _ in COMMANDS]:\n"
            "    with contextlib.redirect_stdout(io.StringIO()):\n"
            "        assert main(argv) == 0, argv\n"
            "print(sorted(m for m in ('torch', 'numba', 'scipy', 'pyrender', 'OpenGL') if m in sys.modules))\n")
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert res.returncode == 0 and res.stdout.strip() == "[]", (res.stdout, res.stderr)


def test_info_columns_stay_aligned_with_long_rows():
    from torch4dtree.cli.info import format_tables

    def seq(name, layers, times):
        return {"name": name, "frames": len(layers), "skipped": [], "times": times,
                "branches": [sum(x) for x in layers], "branches_per_layer": layers,
                "height": [1.5 * sum(x) for x in layers], "total_length": [1234.5 * sum(x) for x in layers]}

    lines = format_tables([seq("a", [[1], [1, 3]], [0.0, 1.0]),
                           seq("b", [[1, 12, 140, 7, 1], [1, 200, 1000, 12, 3]], [65.0, 112.5])])
    header = lines[1]
    assert lines[5] == header  # the same columns in both tables
    rows = [ln for ln in lines if ln.startswith("  ") and ln != header]
    assert len(rows) == 4
    for col in ("time", "branches", "height", "length"):  # right-aligned numbers end under their header
        end = header.index(col) + len(col)
        for row in rows:
            assert row[end - 1] != " " and (end == len(row) or row[end] == " "), (col, row)
    start = header.index("per layer")
    assert all(row[start - 1] == " " and row[start] != " " for row in rows)


def test_config_literals_match_the_trees_module():
    """config.py keeps these literal so that it never imports torch; they must agree with the tree code."""
    from torch4dtree.config import HIERARCHIES, Config
    from torch4dtree.trees import skeleton
    from torch4dtree.trees.structures import DEFAULT_T

    assert Config().T == DEFAULT_T and HIERARCHIES == skeleton.HIERARCHIES


# ----------------------------------------------------------------------------- exit codes and --debug
def test_bad_input_is_exit_2_without_the_bug_note(capsys, tmp_path):
    bad = tmp_path / "bad.swc"
    bad.write_text("1 0 0 0 0 1 -1\n2 0 0 0 1 1 5\n")
    assert main(["info", str(bad)]) == 2
    line = one_line_error(capsys, "info")
    assert "bug" not in line
    config = tmp_path / "bad.json"
    config.write_text('{"T": 1}')
    assert main(["info", str(bad), "--config", str(config)]) == 2
    assert "T must be an integer >= 2" in one_line_error(capsys, "info")


@pytest.mark.parametrize("error", [ValueError("an internal check failed"), RuntimeError("an internal check failed"),
                                   KeyError("slot")])
def test_an_internal_error_is_exit_1_with_the_bug_note(capsys, monkeypatch, tmp_path, error):
    from torch4dtree.cli import info
    from torch4dtree.cli.main import BUG_NOTE

    def broken(*args, **kwargs):
        raise error

    monkeypatch.setattr(info, "info", broken)
    assert main(["info", str(tmp_path)]) == 1
    line = one_line_error(capsys, "info")
    assert line.endswith(f"({BUG_NOTE})"), line


def test_an_environment_error_is_exit_1_without_the_bug_note(capsys, monkeypatch, tmp_path):
    from torch4dtree.cli import info

    def missing(*args, **kwargs):
        raise ModuleNotFoundError("rendering needs the 'render' extra", name="pyrender")

    monkeypatch.setattr(info, "info", missing)
    assert main(["info", str(tmp_path)]) == 1
    assert "bug" not in one_line_error(capsys, "info")


@pytest.mark.parametrize("where", ["before", "after"])
def test_debug_prints_the_traceback(capsys, monkeypatch, tmp_path, where):
    from torch4dtree.cli import info

    def broken(*args, **kwargs):
        raise RuntimeError("an internal check failed")

    monkeypatch.setattr(info, "info", broken)
    argv = ["--debug", "info", str(tmp_path)] if where == "before" else ["info", str(tmp_path), "--debug"]
    assert main(argv) == 1
    err = capsys.readouterr().err
    assert err.startswith("Traceback (most recent call last):") and "in broken" in err, err
    assert err.rstrip("\n").split("\n")[-1].startswith("torch4dtree info: error: an internal check failed")
    monkeypatch.undo()
    assert main(["--debug", "info", str(tmp_path / "missing")]) == 2  # input errors keep their code
    assert "Traceback" in capsys.readouterr().err
