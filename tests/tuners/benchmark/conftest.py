"""The quick benchmark, run once per test run for the benchmark's and the leaderboard's tests
(once across parallel workers: ``run_once`` in tests/conftest.py)."""

import json

import pytest

from tuners.benchmark import command as benchmark


@pytest.fixture(scope="session")
def quick(run_once):
    def compute(folder):
        code = benchmark.main(["--quick", "--out", str(folder / "results")])
        assert code == 0

    out = run_once("quick-benchmark", compute) / "results"
    return out, json.loads((out / "benchmark.json").read_text())
