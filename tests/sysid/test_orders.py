"""Order selection with validation data (issue 13, defects 4 and 6a).

4. Higher orders fell into local minima without a word: on a flexible-link record a higher
   order fitted worse than a lower one it contains, a 3/0 fit put a pole far beyond Nyquist,
   and ``--offset initial`` and ``--offset mean`` converged to different 2/1 models.
6a. The fit reported was the one on the estimation data; there was no validation split.
"""

from __future__ import annotations

import numpy as np
import pytest

from gripper_env.sim import simulate
from gripper_env.sysid import tfest

from .cli_support import run, run_json, write_log
from .signals import lsim_zoh

DT = 1e-3
# a flexible link: a rigid mode at 6 rad/s and a lightly damped one at 40 rad/s with an
# anti-resonance at 28 rad/s (4 poles, 2 zeros), unit gain
W1, Z1, W2, Z2, WZ, ZZ = 6.0, 0.6, 40.0, 0.05, 28.0, 0.04
FLEX_DEN = np.polymul([1, 2 * Z1 * W1, W1**2], [1, 2 * Z2 * W2, W2**2])
FLEX_NUM = np.array([1, 2 * ZZ * WZ, WZ**2]) * (W1**2 * W2**2 / WZ**2)


@pytest.fixture(scope="module")
def flexible_log(tmp_path_factory):
    rng = np.random.default_rng(0)
    n = 20000
    u = np.zeros(n)
    k = 200
    while k < n:
        m = int(rng.uniform(50, 400))
        u[k : k + m] = rng.uniform(-1, 1)
        k += m
    y0 = lsim_zoh(FLEX_NUM, FLEX_DEN, u, DT)
    y = y0 + rng.normal(0, 0.02 * np.std(y0), n)
    path = tmp_path_factory.mktemp("flex") / "flex.csv"
    return write_log(path, np.arange(n) * DT, desired_deg=u, actual_deg=y)


def test_higher_orders_never_fit_worse_than_the_orders_they_contain(flexible_log, capsys):
    out = run_json(
        [str(flexible_log), "--orders", "2/0,2/1,4/0,4/1,4/2", "--split", "0.5", "--offset",
         "none", "--delay", "0"],
        capsys,
    )  # fmt: skip
    rows = {row["order"]: row for row in out["orders"]["candidates"]}
    for big, small in (("4/0", "2/0"), ("4/1", "2/1"), ("4/1", "2/0"), ("4/2", "2/1")):
        assert rows[big]["fit_pct"] >= rows[small]["fit_pct"] - 0.01, (big, small)
    # the true structure wins on validation data, and that is the headline
    assert out["orders"]["chosen"] == "4/2"
    assert out["validation"]["fit_pct"] > 97.0
    assert rows["4/2"]["validation_fit_pct"] > max(
        r["validation_fit_pct"] for o, r in rows.items() if o != "4/2"
    )


def test_a_pole_beyond_nyquist_is_flagged(flexible_log, capsys):
    status, out, err = run(
        [str(flexible_log), "--poles", "3", "--zeros", "0", "--offset", "none", "--json"], capsys
    )
    assert status == 0
    assert "beyond the Nyquist frequency" in err
    import json

    assert any("Nyquist" in w for w in json.loads(out).get("warnings", []))


def test_the_operating_point_does_not_decide_the_model():
    """On a friction record (20 s slopes of the simulated actual gripper) the output-error cost
    is flat; main's 2/1 fits went to a non-minimum-phase optimum (poles -818 and -5 rad/s) with
    --offset initial and to (poles -3 and -0.2) with --offset mean."""
    traj = simulate("test2", "slope20", gains=None, disturbance="actual", seeds=1)
    u, y = traj.r[0], traj.y[0]
    a = tfest(DT, u, y, offset="initial")
    b = tfest(DT, u, y, offset="mean")
    assert a.fit_pct == pytest.approx(b.fit_pct, abs=0.01)
    np.testing.assert_allclose(np.sort(a.poles.real), np.sort(b.poles.real), rtol=0.02, atol=0.01)
    assert np.all(a.zeros.real < 0)  # minimum phase, like the servo


def test_the_fit_on_validation_data_is_the_headline(flexible_log, capsys):
    status, out, _ = run([str(flexible_log), "--poles", "4", "--zeros", "2", "--split", "0.3",
                          "--offset", "none"], capsys)  # fmt: skip
    assert status == 0
    lines = out.splitlines()
    assert lines[0].startswith("G(s) = ")
    assert lines[1].startswith("fit on validation data (last 30 % of flex.csv")
    assert lines[2].startswith("fit on the estimation data")


def test_an_order_that_did_not_converge_is_listed_but_not_chosen():
    # CI's README walk: 3/1 stopped at the iteration limit 1.1 points above 1/0 and 2/1, was
    # chosen, and the command exited 1 on a record whose other orders converged
    from gripper_env.sysid.orders import choose_order

    figures = dict(n_params=[2, 4, 5], aic=[-100932.0, -101106.0, -150644.0])
    chosen, rule = choose_order(
        converged=[True, True, False], validation_fit_pct=[95.63, 95.67, 96.80], **figures
    )
    assert chosen == 0 and rule.endswith("orders that did not converge are not chosen")
    # the parsimony rule among the converged: 2/1 is 0.6 points above 1/0, so it wins
    assert choose_order(converged=[True, True, False], validation_fit_pct=[95.0, 95.6, 99.0],
                        **figures)[0] == 1  # fmt: skip
    # by AIC without validation data, again among the converged only
    assert choose_order(converged=[True, True, False], validation_fit_pct=None, **figures)[0] == 1
    # when none converged the rule is the plain one (and the command says so and exits 1)
    chosen, rule = choose_order(
        converged=[False] * 3, validation_fit_pct=[95.63, 95.67, 96.80], **figures
    )
    assert chosen == 2 and "not chosen" not in rule
