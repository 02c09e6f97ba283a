"""Where configurations come from: the package (importlib.resources), GRIPPER_CONFIG_DIR, paths."""

from __future__ import annotations

import os
import subprocess
import sys
from importlib.resources import files

import pytest
import yaml

import gripper_env.config as config
from gripper_env.config import ConfigError, config_file, find_config
from gripper_env.disturbances import available_disturbances, load_disturbance
from gripper_env.objective import load_objective
from gripper_env.plants import available_plants, load_plant


def test_the_shipped_configs_are_the_package_gripper_env_configs():
    shipped = files("gripper_env.configs")
    assert config.SHIPPED == shipped
    assert (shipped / "plants" / "test2.yaml").is_file()
    assert find_config("plants", "test2") == shipped / "plants" / "test2.yaml"
    assert {"test1", "test2", "test3", "test4"} <= set(available_plants())


@pytest.fixture
def own_configs(tmp_path, monkeypatch):
    """A user's folder with one plant and a changed objective, as GRIPPER_CONFIG_DIR names it."""
    (tmp_path / "plants").mkdir()
    (tmp_path / "plants" / "mine.yaml").write_text(
        yaml.safe_dump({"name": "mine", "num": [10.0], "den": [1.0, 10.0]})
    )
    objective = yaml.safe_load(config_file("objective.yaml").read_text())
    objective["weights"]["iae"] = 3.0
    (tmp_path / "objective.yaml").write_text(yaml.safe_dump(objective))
    monkeypatch.setattr(config, "CONFIG_DIR", tmp_path)
    return tmp_path


def test_a_users_folder_comes_first_and_the_shipped_files_stay(own_configs):
    assert tuple(load_plant("mine").den) == (1.0, 10.0)
    assert tuple(load_plant("test2").den) == (2.0, 20.68, 0.003084)  # still in the package
    assert {"mine", "test1", "test4"} <= set(available_plants())
    assert load_objective().weights.iae == 3.0  # the user's file wins over the shipped one
    assert set(available_disturbances()) >= {"ideal", "actual"}
    assert load_disturbance("actual").name == "actual"
    with pytest.raises(ConfigError, match=r"unknown plant 'nope'; available: mine, test1"):
        load_plant("nope")


def test_a_path_is_read_as_it_is(tmp_path):
    path = tmp_path / "other.yaml"
    path.write_text(yaml.safe_dump({"name": "other", "num": [5.0], "den": [1.0, 5.0]}))
    assert load_plant(path).name == "other" and load_plant(str(path)).name == "other"
    with pytest.raises(ConfigError, match=r"plant file .*missing\.yaml' does not exist"):
        load_plant(tmp_path / "missing.yaml")


def test_gripper_config_dir_is_read_from_the_environment(tmp_path):
    env = dict(os.environ, GRIPPER_CONFIG_DIR=str(tmp_path))
    code = "import gripper_env.config as c; print(c.CONFIG_DIR, c.SHIPPED != c.CONFIG_DIR)"
    out = subprocess.run(
        [sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True
    ).stdout.split()
    assert out == [str(tmp_path), "True"]
