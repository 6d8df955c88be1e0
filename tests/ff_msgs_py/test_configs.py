"""ff_msgs_py.configs: the shipped configuration files by name (source checkout here; the wheel's
package data is checked by tests/test_packaging.py)."""
from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from ff_msgs_py import configs

REPO_CONFIG = Path(__file__).resolve().parents[2] / "config"


def test_the_checkout_config_folder_is_the_source_of_truth():
    assert configs.config_dir() == REPO_CONFIG
    assert configs.available() == sorted(p.name for p in REPO_CONFIG.glob("*.yaml"))
    assert "planner.yaml" in configs.available()


def test_load_by_name_with_or_without_suffix():
    want = yaml.safe_load((REPO_CONFIG / "planner.yaml").read_text())
    assert configs.load_config("planner.yaml") == want == configs.load_config("planner")
    assert configs.config_path("planner") == REPO_CONFIG / "planner.yaml"
    params = configs.node_parameters("planner.yaml", "ff_planner")
    assert params == want["ff_planner"]["ros__parameters"] and "switch_grid" in params
    assert configs.node_parameters("planner.yaml", "no_such_node") == {}


@pytest.mark.parametrize("name", ["plannr.yaml", "planner.txt", "../pyproject.toml", "../config/planner.yaml", ""])
def test_unknown_names_list_the_available_ones(name):
    with pytest.raises(configs.ConfigNotFound, match="available: .*planner.yaml"):
        configs.config_path(name)


def test_the_package_folder_is_used_where_there_is_no_checkout(monkeypatch, tmp_path):
    shipped = tmp_path / "config"
    shipped.mkdir()
    (shipped / "only.yaml").write_text("a:\n  ros__parameters:\n    x: 1\n")
    monkeypatch.setattr(configs, "_source_dir", lambda: None)
    monkeypatch.setattr(configs, "_package_dir", lambda: shipped)
    assert configs.available() == ["only.yaml"] and configs.node_parameters("only", "a") == {"x": 1}
    monkeypatch.setattr(configs, "_package_dir", lambda: None)
    with pytest.raises(configs.ConfigNotFound, match="reinstall"):
        configs.config_dir()


def test_ff_config_lists_prints_and_copies(tmp_path, capsys):
    assert configs.main([]) == 0
    assert "planner.yaml" in capsys.readouterr().out.split()
    assert configs.main(["planner"]) == 0
    assert capsys.readouterr().out == (REPO_CONFIG / "planner.yaml").read_text()
    assert configs.main(["--copy", str(tmp_path / "mine"), "planner.yaml"]) == 0
    assert (tmp_path / "mine" / "planner.yaml").read_text() == (REPO_CONFIG / "planner.yaml").read_text()
    (tmp_path / "mine" / "planner.yaml").write_text("edited")
    assert configs.main(["--copy", str(tmp_path / "mine")]) == 0       # all; the edited one is kept
    assert (tmp_path / "mine" / "planner.yaml").read_text() == "edited"
    assert sorted(p.name for p in (tmp_path / "mine").iterdir()) == configs.available()
    assert configs.main(["nope"]) == 2 and "available" in capsys.readouterr().err
