"""The README works for a newcomer: its set-up commands are the ones CI runs, and its quick start runs as written.

How the quick start is found: every fenced block (```bash or ```python) between the heading "## Quick start" and the
next "## " heading of README.md. The bash blocks run line by line in a temporary folder (with a link to the
repository's ``configs/``), a leading ``torch4dtree`` replaced by ``python -m torch4dtree.cli`` of this interpreter;
then the python blocks run there too. Nothing reads the real Pheno4D data.
"""

import ast
import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text()


def fenced(text: str, lang: str) -> list[str]:
    return re.findall(rf"```{lang}\n(.*?)\n```", text, flags=re.S)


def bash_blocks() -> list[str]:
    return fenced(README, "bash")


def quick_start() -> str:
    match = re.search(r"^## Quick start\n(.*?)(?=^## )", README, flags=re.S | re.M)
    assert match, "README.md has no '## Quick start' section"
    return match.group(1)


def python_example() -> str:
    blocks = fenced(quick_start(), "python")
    assert blocks, "the quick start has no python block"
    return "\n".join(blocks)


def test_readme_has_exactly_two_setup_commands():
    blocks = [b for b in bash_blocks() if "pip install" in b]
    assert len(blocks) == 2, blocks
    assert all("torch==2.13.0" in b and b.index("torch==2.13.0") < b.index("-e ") for b in blocks)


def test_ci_runs_the_readme_test_command():
    test_cmd = next(b for b in bash_blocks() if "pytest" in b)
    ci_lines = (ROOT / ".ci" / "run").read_text().splitlines()
    assert test_cmd.strip() in [line.strip() for line in ci_lines]


def test_readme_commands_use_only_existing_subcommands():
    from torch4dtree.cli import build_parser

    choices = build_parser()._subparsers._group_actions[0].choices
    main_cmd = next(b for b in bash_blocks() if "pip install" in b and "synth" in b)
    for block in [main_cmd, *fenced(quick_start(), "bash")]:
        for used in re.findall(r"torch4dtree (\w+)", block):
            assert used in choices, used


def test_readme_quick_start_runs_on_synthetic_data(tmp_path, monkeypatch, capsys):
    """The quick start's shell commands, then its Python, exactly as written, in an empty folder."""
    (tmp_path / "configs").symlink_to(ROOT / "configs")
    path = [str(ROOT), *filter(None, os.environ.get("PYTHONPATH", "").split(os.pathsep))]
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(path), "TORCH4DTREE_PHENO4D": str(tmp_path / "no_real_data")}
    lines = [line for block in fenced(quick_start(), "bash") for line in block.splitlines() if line.strip()]
    assert lines and all(line.startswith("torch4dtree ") for line in lines), lines
    for line in lines:
        argv = [sys.executable, "-m", "torch4dtree.cli", *shlex.split(line)[1:]]
        done = subprocess.run(argv, cwd=tmp_path, env=env, capture_output=True, text=True, timeout=600)
        assert done.returncode == 0, (line, done.stdout, done.stderr)
    before = sorted(p.name for p in ROOT.iterdir())
    written = sorted(p.name for p in tmp_path.iterdir())
    monkeypatch.chdir(tmp_path)
    exec(compile(python_example(), "README.md", "exec"), {})
    out = capsys.readouterr().out
    assert "morph.png" in out  # it did write the picture (into a folder it removed)
    assert sorted(p.name for p in tmp_path.iterdir()) == written  # the Python block writes nothing
    assert sorted(p.name for p in ROOT.iterdir()) == before


def test_readme_python_example_imports_only_what_it_uses():
    tree = ast.parse(python_example())
    imported = {a.asname or a.name.split(".")[0] for node in ast.walk(tree)
                if isinstance(node, (ast.Import, ast.ImportFrom)) for a in node.names}
    used = {n.id for n in ast.walk(tree) if isinstance(n, ast.Name)}
    assert imported <= used, imported - used


def test_readme_is_a_users_document():
    assert len(README.splitlines()) < 250
    for word in ("commit", "today", "previous", "SPEC", "DESIGN.md"):
        assert not re.search(rf"\b{word}\b", README, flags=re.I), word


def test_readme_links_resolve():
    for target in re.findall(r"\]\(([^)#:]+)(?:#[^)]*)?\)", README):
        assert (ROOT / target).exists(), target


def test_method_has_the_fixed_sections():
    method = (ROOT / "docs" / "method.md").read_text()
    heads = re.findall(r"^## §(\d+) ", method, flags=re.M)
    assert heads == [str(i) for i in range(1, 8)], heads
    assert not re.search(r"\bSPEC\b|DESIGN\.md", method)


def test_the_real_data_location_is_documented_where_it_is_read(monkeypatch, tmp_path):
    from torch4dtree.bench.trees import default_data_root

    assert "TORCH4DTREE_PHENO4D" in README and "github.com/Tahmina979/4Dtreeshape_project" in README
    assert "TORCH4DTREE_PHENO4D" in (ROOT / "tests" / "conftest.py").read_text()
    monkeypatch.delenv("TORCH4DTREE_PHENO4D", raising=False)
    assert default_data_root() == ROOT.parent / "shared" / "data" / "pheno4d"  # "../shared/data/pheno4d"
    monkeypatch.setenv("TORCH4DTREE_PHENO4D", str(tmp_path))
    assert default_data_root() == tmp_path
