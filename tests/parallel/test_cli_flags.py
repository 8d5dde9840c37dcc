"""``--workers`` / ``--scheduler`` on the heavy commands."""

from __future__ import annotations

import argparse

import pytest

from torch4dtree.cli import build_parser
from torch4dtree.cli.options import UsageError, executor_from_args
from torch4dtree.parallel import InlineExecutor


@pytest.mark.parametrize("command", ["fit", "evaluate", "register4d"])
def test_heavy_commands_take_the_flags(command):
    sub = build_parser()._subparsers._group_actions[0].choices[command]
    flags = {o for a in sub._actions for o in a.option_strings}
    assert {"--workers", "--scheduler"} <= flags


def test_executor_from_args():
    with executor_from_args(argparse.Namespace(workers=None, scheduler=None)) as ex:
        assert ex is None  # every entry point keeps its in-process default
    with executor_from_args(argparse.Namespace(workers=1, scheduler=None)) as ex:
        assert isinstance(ex, InlineExecutor)
    with pytest.raises(UsageError, match="not both"):
        executor_from_args(argparse.Namespace(workers=2, scheduler="tcp://x:1"))


def test_fit_on_two_workers_writes_a_model(synthetic_folder, tmp_path):
    from torch4dtree.cli import main

    data = synthetic_folder(3, 0, 3, kind="maize")
    assert main(["fit", str(data), "--out", str(tmp_path / "run"), "--workers", "2", "--no-figures", "--quiet",
                 "--T", "8", "--n-t", "4"]) == 0
    assert (tmp_path / "run" / "model.pt").exists()
