"""The README's set-up commands are the ones CI runs."""

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def bash_blocks() -> list[str]:
    return re.findall(r"```bash\n(.*?)\n```", (ROOT / "README.md").read_text(), flags=re.S)


def test_readme_has_exactly_two_setup_commands():
    blocks = [b for b in bash_blocks() if "pip install" in b]
    assert len(blocks) == 2, blocks
    assert all("torch==2.13.0" in b and b.index("torch==2.13.0") < b.index("-e ") for b in blocks)


def test_ci_runs_the_readme_test_command():
    test_cmd = next(b for b in bash_blocks() if "pytest" in b)
    ci_lines = (ROOT / ".ci" / "run").read_text().splitlines()
    assert test_cmd.strip() in [line.strip() for line in ci_lines]


def test_main_command_uses_only_existing_subcommands():
    from torch4dtree.cli import build_parser

    main_cmd = next(b for b in bash_blocks() if "synth" in b)
    choices = build_parser()._subparsers._group_actions[0].choices
    for used in re.findall(r"torch4dtree (\w+)", main_cmd):
        assert used in choices, used


def python_example() -> str:
    return next(b for b in re.findall(r"```python\n(.*?)\n```", (ROOT / "README.md").read_text(), flags=re.S))


def test_readme_python_example_runs_and_leaves_no_files(tmp_path, monkeypatch, capsys):
    from conftest import PHENO4D, pheno4d

    pheno4d("swc", "Tomato_3")
    code = python_example().replace('"../shared/data/pheno4d/', f'"{PHENO4D}/')
    before = sorted(p.name for p in ROOT.iterdir())
    monkeypatch.chdir(tmp_path)
    exec(compile(code, "README.md", "exec"), {})
    out = capsys.readouterr().out
    assert "morph.png" in out  # it did write the picture (into a folder it removed)
    assert list(tmp_path.iterdir()) == [] and sorted(p.name for p in ROOT.iterdir()) == before


def test_readme_python_example_imports_only_what_it_uses():
    import ast

    tree = ast.parse(python_example())
    imported = {a.asname or a.name.split(".")[0] for node in ast.walk(tree)
                if isinstance(node, (ast.Import, ast.ImportFrom)) for a in node.names}
    used = {n.id for n in ast.walk(tree) if isinstance(n, ast.Name)}
    assert imported <= used, imported - used


def test_the_real_data_location_is_documented_where_it_is_read(monkeypatch, tmp_path):
    from torch4dtree.bench.trees import default_data_root

    readme = (ROOT / "README.md").read_text()
    assert "TORCH4DTREE_PHENO4D" in readme and "github.com/Tahmina979/4Dtreeshape_project" in readme
    assert "TORCH4DTREE_PHENO4D" in (ROOT / "tests" / "conftest.py").read_text()
    monkeypatch.delenv("TORCH4DTREE_PHENO4D", raising=False)
    assert default_data_root() == ROOT.parent / "shared" / "data" / "pheno4d"  # "../shared/data/pheno4d"
    monkeypatch.setenv("TORCH4DTREE_PHENO4D", str(tmp_path))
    assert default_data_root() == tmp_path
