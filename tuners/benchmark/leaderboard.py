"""The benchmark's verdict: which rows may be ranked, their ranking, significance, the report.

A row is **ranked** only if a control engineer could deploy it: the loop as it runs (with the
servo's command hold) is stable, every held-out run stayed stable, it meets the robustness
constraints (``Ms`` and gain margin, ``configs/objective.yaml``) and the jaw actually moves (the
grip reaches 90 % of the way). Rows that miss are listed with the reason, never ranked.

Ranked rows are ordered by the objective's cost on the actual model (mean over the held-out
seeds; ``configs/objective.yaml``: what every search minimises, IAE first), with IAE beside it.
Differences are tested **paired over the held-out seeds** (every row meets the same friction,
noise and stop draws): a Wilcoxon signed-rank test of the per-seed cost of each row against the
best textbook baseline of its plant, two-sided, at 5 %. With 10 seeds the smallest possible p is
0.002.
"""

from __future__ import annotations

import math
import sys
from pathlib import Path
from typing import Any

import numpy as np
from scipy import stats

__all__ = ["figures", "rank", "render_head", "render_markdown", "update_readme", "why_not_ranked"]

ALPHA = 0.05


def why_not_ranked(row: dict[str, Any]) -> str | None:
    """Why a row may not be ranked (``None`` if it may)."""
    rb = row["robustness"]
    actual = row["metrics"]["actual"]
    if not rb.get("stable", False):
        return "unstable loop (with the servo's command hold)"
    if actual["stable_fraction"] < 1.0:
        return "diverged on some held-out seeds"
    rise = actual["mean"]["grip"]["rise_time_s"]
    if rise is None or not math.isfinite(rise):
        return "the jaw does not complete the grip"
    if not rb.get("meets_constraints", False):
        ms, gm = rb.get("ms"), rb.get("gain_margin_db")
        lim = rb.get("constraints", {})
        ms_max, gm_min = lim.get("ms_max", math.inf), lim.get("gm_min_db", 0.0)
        misses = []
        if ms is None or ms > ms_max:
            misses.append(f"Ms {_f(ms)} > {ms_max:g}")
        if gm is not None and gm < gm_min:
            misses.append(f"gain margin {_f(gm)} dB < {gm_min:g} dB")
        return (
            "misses the robustness constraints with the servo hold ("
            + (", ".join(misses) or "a lower gain margin")
            + ")"
        )
    return None


def _cost(row: dict[str, Any]) -> float:
    return float(row["metrics"]["actual"]["mean"]["cost"])


def paired_test(a: list[float], b: list[float]) -> tuple[float, float]:
    """Mean of ``a - b`` and the two-sided Wilcoxon signed-rank p-value."""
    d = np.asarray(a, dtype=float) - np.asarray(b, dtype=float)
    if not np.all(np.isfinite(d)):
        return math.inf, 0.0
    if np.allclose(d, 0.0):
        return 0.0, 1.0
    return float(d.mean()), float(stats.wilcoxon(d, zero_method="zsplit").pvalue)


def rank(data: dict[str, Any]) -> dict[str, Any]:
    """Per plant: ranked rows with significance against the best baseline; overall: per tuner
    over the plants."""
    per_plant: dict[str, Any] = {}
    for plant, pdata in data["plants"].items():
        if not pdata.get("feasible"):
            continue
        rows = pdata["tuners"]
        reasons = {name: why_not_ranked(r) for name, r in rows.items()}
        ranked = sorted(
            (n for n, why in reasons.items() if why is None), key=lambda n: _cost(rows[n])
        )
        baselines = [n for n in ranked if rows[n]["kind"] == "baseline"]
        best_base = baselines[0] if baselines else None
        tests = {}
        for name in ranked:
            entry: dict[str, Any] = {}
            for ref in filter(None, (best_base, "command=reference")):
                if ref == name or ref not in rows:
                    continue
                diff, p = paired_test(rows[name]["per_seed_cost"], rows[ref]["per_seed_cost"])
                verdict = "n.s." if p >= ALPHA else ("better" if diff < 0 else "worse")
                entry[ref] = {"mean_cost_difference": diff, "p_value": p, "verdict": verdict}
            tests[name] = entry
        per_plant[plant] = {
            "ranked": ranked,
            "not_ranked": {n: why for n, why in reasons.items() if why is not None},
            "best_baseline": best_base,
            "tests": tests,
        }
    return {"per_plant": per_plant, "overall": _overall(data, per_plant)}


def _overall(data: dict[str, Any], per_plant: dict[str, Any]) -> list[dict[str, Any]]:
    """One line per tuner over the feasible plants (the README's head)."""
    names: list[str] = []
    for plant in per_plant:
        for n in data["plants"][plant]["tuners"]:
            if n not in names:
                names.append(n)
    out = []
    for name in names:
        rows = {p: data["plants"][p]["tuners"].get(name) for p in per_plant}
        rows = {p: r for p, r in rows.items() if r is not None}
        ranked_on = [p for p in rows if name in per_plant[p]["ranked"]]
        actual = [r["metrics"]["actual"]["mean"] for r in rows.values()]
        cross = [r["cross_model"].get("worst", {}) for r in rows.values() if r["cross_model"]]
        better = [
            p for p in ranked_on
            if per_plant[p]["best_baseline"] not in (None, name)
            and per_plant[p]["tests"][name][per_plant[p]["best_baseline"]]["verdict"] == "better"
        ]  # fmt: skip
        out.append(
            {
                "tuner": name,
                "kind": next(iter(rows.values()))["kind"],
                "ranked_on": ranked_on,
                "plants": list(rows),
                "iae": float(np.mean([a["iae"] for a in actual])),
                "cost": float(np.mean([a["cost"] for a in actual])),
                "overshoot_pct": max(
                    max(a["grip"]["overshoot_pct"], a["ungrip"]["overshoot_pct"]) for a in actual
                ),
                "stall_s": max(a["stall_s"] for a in actual),
                "grip_object_stall_s": max(r["grip_object"]["stall_s"] for r in rows.values()),
                "ms": _worst([r["robustness"].get("ms") for r in rows.values()], max),
                "gm_db": _worst(
                    [r["robustness"].get("gain_margin_db") for r in rows.values()], min
                ),
                "cross_ms": _worst([c.get("ms") for c in cross], max) if cross else None,
                "cross_gm_db": _worst([c.get("gain_margin_db") for c in cross], min)
                if cross
                else None,
                "cross_overshoot_pct": _worst([c.get("overshoot_pct") for c in cross], max)
                if cross
                else None,
                "cross_stable": all(c.get("stable", False) for c in cross) if cross else None,
                "beats_best_baseline_on": better,
                "episodes": int(sum(r["episodes"] for r in rows.values())),
                "wall_time_s": float(sum(r["wall_time_s"] for r in rows.values())),
            }
        )
    n_plants = len(per_plant)
    full = [o for o in out if len(o["ranked_on"]) == n_plants]
    rest = [o for o in out if len(o["ranked_on"]) != n_plants]
    full.sort(key=lambda o: o["cost"])
    rest.sort(key=lambda o: (-len(o["ranked_on"]), o["cost"]))
    for i, o in enumerate(full):
        o["rank"] = i + 1
    for o in rest:
        o["rank"] = None
    return full + rest


def _worst(values: list[Any], pick) -> float | None:
    vals = [math.inf if v is None else float(v) for v in values]
    if not vals:
        return None
    return pick(vals)


# ----------------------------------------------------------------------------------------------
# Report


def _f(x: Any, digits: int = 3) -> str:
    if x is None:
        return "-"
    if isinstance(x, bool):
        return "yes" if x else "no"
    if isinstance(x, float) and not math.isfinite(x):
        return "inf" if x > 0 else "-inf"
    return f"{x:.{digits}g}"


def _ci(actual: dict[str, Any], *path: str) -> str:
    def get(d: dict[str, Any]) -> Any:
        for k in path:
            d = d[k]
        return d

    mean, lo, hi = get(actual["mean"]), get(actual["ci95_low"]), get(actual["ci95_high"])
    if mean is None:
        return "never"
    if lo is None or hi is None or hi - lo < 1e-12:
        return _f(mean)
    return f"{_f(mean)} ± {_f((hi - lo) / 2, 2)}"


def render_head(data: dict[str, Any]) -> str:
    """The overall leaderboard as a Markdown table (the report's and the README's head)."""
    lb = data["leaderboard"]
    plants = list(lb["per_plant"])
    lines = [
        f"| rank | tuner | cost (mean over {', '.join(plants)}) | IAE deg·s | worst overshoot % | "
        "stall s | Ms (hold) | GM dB (hold) | other plants: worst Ms / GM dB / OS % | "
        "beats best baseline (p<0.05) on | episodes | wall s |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for o in lb["overall"]:
        rank = str(o["rank"]) if o["rank"] else f"not ranked ({len(o['ranked_on'])}/{len(plants)})"
        cross = (
            f"{_f(o['cross_ms'])} / {_f(o['cross_gm_db'])} / {_f(o['cross_overshoot_pct'])}"
            + ("" if o["cross_stable"] in (None, True) else " (unstable)")
            if o["cross_ms"] is not None
            else "-"
        )
        lines.append(
            f"| {rank} | {o['tuner']} | {_f(o['cost'], 4)} | {_f(o['iae'], 4)} | "
            f"{_f(o['overshoot_pct'])} | "
            f"{_f(o['stall_s'])} | {_f(o['ms'])} | {_f(o['gm_db'])} | {cross} | "
            f"{', '.join(o['beats_best_baseline_on']) or '-'} | {o['episodes']} | "
            f"{o['wall_time_s']:.1f} |"
        )
    return "\n".join(lines)


def render_markdown(data: dict[str, Any], meta: dict[str, Any]) -> str:
    """The benchmark report (Markdown)."""
    lb = data["leaderboard"]
    obj = meta["objective"]
    lim = obj["constraints"]
    lines = [
        "# Benchmark: PID tuners for the hobby-servo gripper",
        "",
        f"Generated by `{meta['command']}` ({meta['date']}, version {meta['version']}, commit "
        f"`{(meta.get('git_commit') or 'unknown')[:10]}`), total wall time "
        f"{meta['wall_time_s']:.0f} s. Profile `{meta['profile']}` (grip step 92 -> 21 deg at "
        f"1 s, un-grip at 10 s, 20 s), actual-gripper preset `{meta['disturbance']}` (stops "
        "beyond 21 and 92 deg, so overshoot is visible), "
        f"{meta['n_seeds']} held-out seeds.",
        "",
        "## Leaderboard",
        "",
        render_head(data),
        "",
        "* **Ranked** only if deployable: stable as the loop really runs (PID at 1 ms, servo "
        f"command held 20 ms), every held-out run stable, Ms <= {lim['ms_max']} and gain margin "
        f">= {lim['gm_min_db']} dB with the hold, and the jaw completes the grip. Ranked by the "
        "objective's cost on the actual model (mean over the feasible plants), the cost every "
        "search minimises; IAE beside it.",
        "* **beats best baseline**: per plant, a paired Wilcoxon signed-rank test of the "
        "per-seed cost against the best-ranked textbook design (`classical-*`), two-sided, "
        f"p < {ALPHA}.",
        "* **other plants**: the same gains on the other identifications of the gripper "
        "(test2-test4; test1 cannot follow the step), worst case over them: Ms and GM with the "
        "hold, actual-model overshoot.",
        "* **episodes**: simulated 20 s episodes the tuner used (all its search seeds); "
        "textbook designs use the model only.",
        f"* Objective (`configs/objective.yaml`): signal `{obj['signal']}` jaw angle, settling "
        "band >= the friction band; weights "
        + ", ".join(f"{k} {v:g}" for k, v in obj["weights"].items() if v)
        + ".",
    ]
    if data.get("rl_note"):
        lines.append(f"* {data['rl_note']}")
    lines += _plant_sections(data, lb)
    lines += [
        "",
        "Figures: `figures/benchmark_pareto.png` (tracking against robustness: every row and "
        "the MIGO front), `figures/benchmark_budget_<plant>.png` (best feasible tuning cost "
        "against simulated episodes), and each row's response plot `<plant>/<tuner>.png`.",
        "",
    ]
    return "\n".join(lines)


def _plant_sections(data: dict[str, Any], lb: dict[str, Any]) -> list[str]:
    lines: list[str] = []
    for plant, pdata in data["plants"].items():
        lines += ["", f"## {plant}", ""]
        if not pdata.get("feasible"):
            lines.append(f"**Not ranked.** {plant}: {pdata['reason']}.")
            continue
        info = lb["per_plant"][plant]
        rows = pdata["tuners"]
        base = info["best_baseline"]
        lines += [
            f"Bang-bang bound (no controller can do better): IAE {_f(pdata['iae_bound'], 4)} "
            f"deg·s. Best baseline: `{base}`.",
            "",
            "| rank | tuner | P | I | D | cost | IAE deg·s | OS % (grip / un-grip) | settle s | "
            "stall s | effort deg | Ms | GM dB | PM deg | vs best baseline (cost) | grip object: "
            "stall s / force / release s | episodes |",
            "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
        ]
        order = info["ranked"] + [n for n in rows if n not in info["ranked"]]
        for name in order:
            r = rows[name]
            a = r["metrics"]["actual"]
            rb = r["robustness"]
            test = info["tests"].get(name, {}).get(base) if base else None
            vs = (
                f"{test['verdict']} ({test['mean_cost_difference']:+.3g}, p={test['p_value']:.3g})"
                if test
                else "-"
            )
            rank = str(info["ranked"].index(name) + 1) if name in info["ranked"] else "-"
            g = r["grip_object"]
            lines.append(
                f"| {rank} | {name} | {_f(r['P'], 4)} | {_f(r['I'], 4)} | {_f(r['D'], 3)} | "
                f"{_ci(a, 'cost')} | {_ci(a, 'iae')} | {_f(a['mean']['grip']['overshoot_pct'])} / "
                f"{_f(a['mean']['ungrip']['overshoot_pct'])} | "
                f"{_f(a['mean']['grip']['settling_time_s'])} | {_f(a['mean']['stall_s'])} | "
                f"{_f(a['mean']['servo_effort_deg'], 4)} | {_f(rb.get('ms'))} | "
                f"{_f(rb.get('gain_margin_db'))} | {_f(rb.get('phase_margin_deg'))} | {vs} | "
                f"{_f(g['stall_s'])} / {_f(g['force_proxy'])} / {_f(g['release_s'])} | "
                f"{r['episodes']} |"
            )
        if info["not_ranked"]:
            lines += ["", "Not ranked:"]
            lines += [f"* `{n}`: {why}" for n, why in info["not_ranked"].items()]
        spread = [
            (n, r["tuning"]) for n, r in rows.items() if "best_cost" in (r.get("tuning") or {})
        ]
        if spread:
            lines += [
                "",
                "Search seeds (best tuning cost per seed: min / median / max; results on a "
                "search bound):",
                "",
            ]
            for n, t in spread:
                c = t["best_cost"]
                bound = "; ".join(t.get("on_bound") or []) or "none on a bound"
                lines.append(
                    f"* `{n}`: {_f(c['min'], 4)} / {_f(c['median'], 4)} / {_f(c['max'], 4)} over "
                    f"{len(t['per_seed'])} seeds; {bound}"
                )
    return lines


def figures(data: dict[str, Any], out: Path) -> list[Path]:
    """The Pareto figure (tracking against robustness) and the budget curves."""
    from tuners.plotting import budget_plot, pareto_plot

    paths = [pareto_plot(data, out / "figures" / "benchmark_pareto.png")]
    for plant, pdata in data["plants"].items():
        if pdata.get("feasible") and pdata.get("curves"):
            paths.append(
                budget_plot(
                    pdata["curves"],
                    f"{plant}: best feasible tuning cost vs simulated episodes",
                    out / "figures" / f"benchmark_budget_{plant}.png",
                )
            )
    return paths


README_START = "<!-- leaderboard:start"
README_END = "<!-- leaderboard:end -->"


def update_readme(readme: Path, data: dict[str, Any]) -> bool:
    """Put the leaderboard's head between the README's leaderboard markers.

    Returns
    -------
    bool
        Whether the README changed.

    Raises
    ------
    ValueError
        The README has no leaderboard markers.
    """
    from gripper_env.files import write_atomic

    text = readme.read_text()
    if README_START not in text or README_END not in text:
        raise ValueError(f"{readme}: no '{README_START} ...' and '{README_END}' markers")
    start = text.index("\n", text.index(README_START)) + 1
    end = text.index(README_END)
    new = text[:start] + render_head(data) + "\n" + text[end:]
    if new != text:
        write_atomic(readme, new)
    return new != text


def main(argv: list[str] | None = None) -> int:
    """``python -m tuners.leaderboard [BENCHMARK_JSON] [--readme README.md]``: print the
    leaderboard's head, or write it into the README."""
    import argparse
    import json

    parser = argparse.ArgumentParser(
        prog="python -m tuners.leaderboard",
        description="Print the benchmark's leaderboard, or put it into the README.",
    )
    parser.add_argument("benchmark", nargs="?", default="results/benchmark.json")
    parser.add_argument("--readme", default=None, help="write it between this file's markers")
    args = parser.parse_args(argv)
    try:
        data = json.loads(Path(args.benchmark).read_text())
        if args.readme:
            changed = update_readme(Path(args.readme), data)
            print(f"{args.readme}: {'updated' if changed else 'already up to date'}")
        else:
            print(render_head(data))
    except (OSError, ValueError, KeyError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
