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


def test_readme_python_example_runs(tmp_path, monkeypatch):
    from conftest import pheno4d

    pheno4d("swc", "Tomato_3")
    code = next(b for b in re.findall(r"```python\n(.*?)\n```", (ROOT / "README.md").read_text(), flags=re.S))
    code = code.replace('"../shared/data/pheno4d/', f'"{ROOT.parent}/shared/data/pheno4d/')
    monkeypatch.chdir(tmp_path)
    exec(compile(code, "README.md", "exec"), {})
    assert (tmp_path / "morph.png").stat().st_size > 1000
