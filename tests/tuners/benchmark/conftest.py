"""The quick benchmark, run once for the benchmark's and the leaderboard's tests."""

import json

import pytest

from tuners.benchmark import command as benchmark


@pytest.fixture(scope="session")
def quick(tmp_path_factory):
    out = tmp_path_factory.mktemp("bench") / "results"
    code = benchmark.main(["--quick", "--out", str(out)])
    assert code == 0
    return out, json.loads((out / "benchmark.json").read_text())
