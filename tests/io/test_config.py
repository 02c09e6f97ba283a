"""Where configurations come from: the package (importlib.resources), GRIPPER_CONFIG_DIR, paths."""

from __future__ import annotations

import os
import subprocess
import sys
from importlib.resources import files

import pytest
import yaml

import gripper_env.io.config as config
from gripper_env.evaluation.objective import load_objective
from gripper_env.io.config import ConfigError, config_file, find_config
from gripper_env.model.disturbances import available_disturbances, load_disturbance
from gripper_env.model.plants import available_plants, load_plant


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
    code = "import gripper_env.io.config as c; print(c.CONFIG_DIR, c.SHIPPED != c.CONFIG_DIR)"
    out = subprocess.run(
        [sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True
    ).stdout.split()
    assert out == [str(tmp_path), "True"]


LOADERS = [yaml.SafeLoader] + ([yaml.CSafeLoader] if hasattr(yaml, "CSafeLoader") else [])


@pytest.mark.parametrize("loader", LOADERS, ids=lambda c: c.__name__)
@pytest.mark.parametrize(
    "text, message",
    [
        ("[" * 10_000, "deeper than 32"),
        ("{a: " * 3000 + "1" + "}" * 3000, "deeper than 32"),
        ("- " * 3000 + "1", "deeper than 32"),
        ("\n".join(["a: &a [1, 1, 1, 1, 1, 1, 1, 1, 1, 1]"]
                   + [f"{c}: &{c} [" + ", ".join([f"*{p}"] * 10) + "]"
                      for p, c in zip("abcd", "bcde", strict=True)]), "100,000 values"),
    ],
    ids=["10,000 [", "3,000-level mapping", "3,000-level list", "aliases of 10^5 values"],
)  # fmt: skip
def test_deep_or_exploding_yaml_is_refused_by_both_parsers(tmp_path, monkeypatch, loader, text,
                                                           message):  # fmt: skip
    """Depth and expanded size are checked on parser events, before any object is built (the
    pure-Python composer recurses: RecursionError at about 1,000 levels)."""
    monkeypatch.setattr(config, "_LOADER", loader)
    path = tmp_path / "hostile.yaml"
    path.write_text(text)
    with pytest.raises(ConfigError) as info:
        config.load_yaml(path)
    text_of = str(info.value)
    assert str(path) in text_of and (message in text_of or "nesting depth" in text_of)


@pytest.mark.parametrize("loader", LOADERS, ids=lambda c: c.__name__)
def test_yaml_at_the_limits_is_read(tmp_path, monkeypatch, loader):
    """32 levels, aliases that expand to fewer than 100,000 values, and a file just under
    1 MiB are ordinary configuration files."""
    monkeypatch.setattr(config, "_LOADER", loader)
    path = tmp_path / "ok.yaml"
    path.write_text("deep: " + "[" * 31 + "1" + "]" * 31 + "\nbase: &b {x: 1}\nother: *b\n")
    data = config.load_yaml(path)
    assert data["other"] == {"x": 1} and data["deep"][0][0] is not None
    path.write_text("x: '" + "a" * (config.MAX_CONFIG_BYTES - 10) + "'\n")
    assert len(config.load_yaml(path)["x"]) == config.MAX_CONFIG_BYTES - 10


def test_a_large_yaml_is_refused_before_it_is_read(tmp_path, monkeypatch):
    path = tmp_path / "large.yaml"
    path.write_text("x: 1\n")
    with path.open("r+b") as f:
        f.truncate(config.MAX_CONFIG_BYTES + 1)  # sparse
    monkeypatch.setattr(config.yaml, "parse", None)  # parsing it would fail differently
    with pytest.raises(ConfigError, match="more than the 1 MiB a configuration file may hold"):
        config.load_yaml(path)
