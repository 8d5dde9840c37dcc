import json
from pathlib import Path

import pytest

from torch4dtree.cli import main
from torch4dtree.config import Config, load_config
from torch4dtree.trees.structures import TreeError

CONFIGS = Path(__file__).resolve().parents[1] / "configs"


@pytest.mark.parametrize("path", sorted(CONFIGS.glob("*.json")), ids=lambda p: p.stem)
def test_shipped_configs_load(path):
    config = load_config(path)
    assert config.load_options().T == config.T


def test_unknown_and_invalid_settings_are_named(tmp_path):
    p = tmp_path / "c.json"
    p.write_text(json.dumps({"T": 32, "rotaton": "so3"}))
    with pytest.raises(TreeError, match=r"c.json: unknown setting\(s\) \['rotaton'\]"):
        load_config(p)
    p.write_text(json.dumps({"rotation": "sideways"}))
    with pytest.raises(TreeError, match="c.json: rotation must be one of"):
        load_config(p)
    p.write_text("{not json")
    with pytest.raises(TreeError, match="cannot read the config"):
        load_config(p)
    with pytest.raises(TreeError, match="lambdas"):
        Config(lambdas=(1.0, -1.0, 1.0))


def test_cli_flags_override_the_config(tmp_path, capsys):
    swc = tmp_path / "t.swc"
    swc.write_text("1 0 0 0 0 1 -1\n2 0 0 0 1 1 1\n3 0 0 0 2 1 2\n4 0 1 0 1.5 1 2\n5 0 2 0 2 1 4\n")
    cfg = tmp_path / "c.json"
    cfg.write_text(json.dumps({"max_layers": 1}))
    assert main(["info", str(swc), "--json", "--config", str(cfg)]) == 0
    assert json.loads(capsys.readouterr().out)["branches"] == 1
    assert main(["info", str(swc), "--json", "--config", str(cfg), "--max-layers", "2"]) == 0
    assert json.loads(capsys.readouterr().out)["branches"] == 2


def test_register_reads_its_settings_from_the_config(tmp_path, capsys):
    """register takes the registration settings (rotation, lambdas, positions, neighbourhood) and the loading ones
    from --config; flags win. Two trees whose side branches sit at s = 0.25 / 0.75: with warped positions lp decides
    the distance; by node rank (the default) both are the stem's first node and cost nothing."""
    a, b = tmp_path / "a.swc", tmp_path / "b.swc"
    a.write_text("1 0 0 0 0 1 -1\n2 0 0 0 1 1 1\n3 0 0 0 4 1 2\n4 0 1 0 1 1 2\n")
    b.write_text("1 0 0 0 0 1 -1\n2 0 0 0 3 1 1\n3 0 0 0 4 1 2\n4 0 1 0 3 1 2\n")
    cfg = tmp_path / "c.json"
    cfg.write_text(json.dumps({"T": 16, "lambdas": [1.0, 1.0, 0.0], "positions": "warped"}))

    def distance(*extra: str) -> float:
        assert main(["register", str(a), str(b), "--json", "--config", str(cfg), *extra]) == 0
        return json.loads(capsys.readouterr().out)["distance_after"]

    free = distance()  # lp = 0 from the config: the parameters cost nothing
    charged = distance("--lambdas", "1", "1", "100")  # the flag overrides the config
    assert free < 1e-6 < charged
    assert distance("--lambdas", "1", "1", "100", "--positions", "rank") < 1e-6
    cfg.write_text(json.dumps({"lambdas": [1.0, 0.0, 1.0]}))
    assert main(["register", str(a), str(b), "--config", str(cfg)]) == 2  # a bad setting: a named error
    assert "ls > 0" in capsys.readouterr().err
