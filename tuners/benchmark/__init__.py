"""The benchmark: every way of choosing a controller, on every plant, as a control engineer judges.

Usage::

    python -m tuners.benchmark                  # the full run (configs/benchmark.yaml)
    python -m tuners.benchmark --quick          # small budgets, two plants (what the test runs)

Modules: :mod:`~tuners.benchmark.settings` (the configuration), :mod:`~tuners.benchmark.run`
(the rows from :mod:`tuners.registry`, on every plant), :mod:`~tuners.benchmark.rows` (one row's
evaluation, and the reference rows), :mod:`~tuners.benchmark.limit` (the least IAE, a linear
program), :mod:`~tuners.benchmark.oracle` (an MPC that knows the model),
:mod:`~tuners.benchmark.leaderboard` (deployability, rankings, tests, the report) and
:mod:`~tuners.benchmark.command` (the command line).
"""
