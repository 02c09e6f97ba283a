"""The grids run through an engine - this process, local worker processes, a Dask cluster
started here - with the same results in the same files."""

import json

import pytest

pytest.importorskip("stable_baselines3")

from tuners import cli
from tuners.engine import engine
from tuners.rl import command as rl


def _square(x: int) -> int:
    return x * x


@pytest.mark.parametrize("spec", ["serial", "local:2"])
def test_an_engine_maps_in_order(spec):
    with engine(spec) as eng:
        assert list(eng.map(_square, range(7))) == [x * x for x in range(7)]


@pytest.mark.parametrize("spec", ["local:0", "nope", "dask-local:x"])
def test_a_bad_engine_is_one_line(spec):
    with pytest.raises(ValueError, match="engine"), engine(spec):
        pass


def _study(tmp_path, engine_spec, small_eval_config):
    args = ["train", "--plant", "test2", "--timesteps", "128", "--seeds", "2", "--no-progress",
            "--json", "--out", str(tmp_path), "--eval-config", str(small_eval_config)]  # fmt: skip
    if engine_spec:
        args += ["--engine", engine_spec]
    assert rl.main(args) == 0
    folder = tmp_path / "rl" / "pid-tune-test2"
    histories = [json.loads((folder / f"seed-{k}" / "history.json").read_text()) for k in (0, 1)]
    models = [(folder / f"seed-{k}" / "model.zip").read_bytes() for k in (0, 1)]
    return histories, models


@pytest.mark.slow
def test_a_dask_cluster_gives_the_results_of_this_process(tmp_path, small_eval_config, capsys):
    """Two training seeds of the RL tuner in this process and on a Dask LocalCluster of two
    worker processes: the same histories and the same model bytes, in the same files."""
    pytest.importorskip("distributed")
    here = _study(tmp_path / "serial", None, small_eval_config)
    there = _study(tmp_path / "dask", "dask-local:2", small_eval_config)
    capsys.readouterr()
    assert here[0] == there[0]
    assert here[1] == there[1]
    assert cli.DEFAULT_OUT.name == "runs"
