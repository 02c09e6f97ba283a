"""``python -m tuners.compile``: its shares cover every warm-up unit once."""

from __future__ import annotations

import pytest

from tuners.compile import _units, main, share


@pytest.mark.parametrize("n", [1, 2, 3, 4])
def test_the_shares_cover_every_unit_exactly_once(n):
    names = list(_units())
    shares = [share(names, k, n) for k in range(n)]
    assert sorted(name for s in shares for name in s) == sorted(names)
    if n > 1:  # the core's share holds no environment; the environments are in the others
        assert not any(name.startswith("environment ") for name in shares[0])
        assert "core and metrics" in shares[0]


@pytest.mark.parametrize("argv", [["--jobs", "0"], ["--shard", "2/2"], ["--shard", "x"]])
def test_bad_jobs_or_shares_are_refused(argv, capsys):
    with pytest.raises(SystemExit) as caught:
        main(argv)
    assert caught.value.code == 2
    assert argv[0] in capsys.readouterr().err
