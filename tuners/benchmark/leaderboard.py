"""The benchmark's verdict: which rows a control engineer would deploy, their ranking, the report.

**Deployable** (:func:`why_not_deployable`): the loop as it runs (PID at 1 ms, servo command
held 20 ms) is stable; every held-out run stays stable and settles (a loop that swings from stop
to stop counts as diverged, :data:`gripper_env.evaluation.metrics.OSCILLATION_LIMIT_DEG`); a PID
meets
``Ms <= ms_max`` and the gain-margin floor with the hold, a learned controller the measured gain
margin that ``Ms <= ms_max`` guarantees a linear loop (:mod:`tuners.probe`); the jaw completes
the grip without touching a stop or stalling. Reference rows (command = reference, a rule at a
fixed setting, the limit, the oracle) are shown, never ranked.

**The headline** ranks gain sets for the *gripper*: its four identifications are fits of one
device and disagree 9x on the fast time constant, so a gain set is admitted only if it is
deployable on every one of ``robust_plants`` (test2-test4; test1 cannot follow the step
profile). Candidates are the robust rows (tuned once on all of them) and every per-plant gain
set (tuned on one, evaluated on the others). **Per-plant tables** rank the rows tuned for one
identification, on that identification only.

Rows are ranked by the objective's cost on the actual model (mean over the held-out seeds, and
over the plants in the headline), IAE beside it. Differences are tested **paired over the
held-out seeds**: a two-sided Wilcoxon signed-rank test of the per-seed costs against the best
deployable textbook row (``baseline`` kind: a rule with its knob set under the constraints), at
5 %; with 10 seeds the smallest possible p is 0.002.
"""

from __future__ import annotations

import math
import sys
from pathlib import Path
from typing import Any

import numpy as np

from tuners.statistics import holm, paired_test

__all__ = [
    "ALPHA",
    "figures",
    "paired_test",
    "rank",
    "render_head",
    "render_markdown",
    "stored",
    "update_readme",
    "why_not_deployable",
]

ALPHA = 0.05
RANKED_KINDS = ("manual", "baseline", "search", "controller")
#: The bare servo's key: the reference row ``command=reference`` of every plant (the servo
#: commanded the reference, its own position loop only), a headline row like the others.
BARE = "command=reference"
BARE_LABEL = "bare servo (command = reference, no host loop)"


def _f(x: Any, digits: int = 3) -> str:
    if x is None:
        return "-"
    if isinstance(x, bool):
        return "yes" if x else "no"
    if isinstance(x, float) and not math.isfinite(x):
        return "inf" if x > 0 else "-inf"
    return f"{x:.{digits}g}"


def why_not_deployable(row: dict[str, Any]) -> str | None:
    """Why a control engineer would not deploy a row (``None``: deployable): the admission
    rule's first missed constraint on the row's held-out runs
    (:mod:`gripper_env.evaluation.admission`, recorded in the row as ``admission``). A row
    recorded without it (older data) is judged on what it has."""
    adm = row.get("admission")
    if adm:
        return None if adm["admitted"] else adm["reason"]
    rb = row["robustness"]
    actual = row["metrics"]["actual"]
    if rb.get("linear", True) and not rb.get("stable", False):
        rho = rb.get("max_pole_magnitude")
        growth = ""
        if rho and rho > 0 and rb.get("refresh_period_s"):
            growth = f", growing x{rho:.3g} per servo frame"
        return f"unstable with the servo's hold (spectral radius {_f(rho)}{growth})"
    if actual["stable_fraction"] < 1.0:
        n = actual["n_seeds"]
        bad = round((1 - actual["stable_fraction"]) * n)
        return f"{bad} of {n} held-out runs diverge or swing from stop to stop"
    rise = actual["mean"]["grip"]["rise_time_s"]
    if rise is None or not math.isfinite(rise):
        return "the jaw does not complete the grip"
    if row["kind"] == "controller":
        mm = row["measured_margins"]
        gm = math.inf if mm["gain_margin_db"] is None else mm["gain_margin_db"]
        if gm < mm["required_gain_margin_db"]:
            return (f"limit-cycle onset {_f(gm)} dB < the {mm['required_gain_margin_db']:.3g} "
                    "dB gain margin that Ms <= 1.6 guarantees a linear loop")  # fmt: skip
    elif not rb.get("meets_constraints", False):
        lim = rb.get("constraints", {})
        ms, gm = rb.get("ms"), rb.get("gain_margin_db")
        misses = []
        if ms is None or ms > lim.get("ms_max", math.inf):
            misses.append(f"Ms {_f(ms)} > {lim.get('ms_max', 0):g}")
        if gm is not None and gm < lim.get("gm_min_db", 0.0):
            misses.append(f"gain margin {_f(gm)} dB < {lim.get('gm_min_db', 0):g} dB")
        return ("misses the robustness constraints with the servo hold ("
                + (", ".join(misses) or "a lower gain margin") + ")")  # fmt: skip
    contact = actual["mean"].get("contact_s") or 0.0
    stall = actual["mean"].get("stall_s") or 0.0
    if stall > 0:
        return f"stalls against a stop ({_f(stall)} s)"
    if contact > 0:
        return f"hits a mechanical stop ({_f(contact)} s in contact)"
    return None


def family_of(name: str) -> str:
    """The family of a row by its name: ``manual``, ``textbook``, ``optuna``, ``rl-tune``,
    ``rl-controller``, ``bare servo`` (``other`` for a row from elsewhere)."""
    if name == BARE:
        return "bare servo"
    for prefix, family in (("manual-", "manual"), ("classical-", "textbook"),
                           ("optuna", "optuna"), ("rl-tune", "rl-tune"),
                           ("rl-controller", "rl-controller")):  # fmt: skip
        if name.startswith(prefix):
            return family
    return "other"


def rule_of(name: str) -> str | None:
    """A textbook row's rule (``classical-amigo-pi-robust`` -> ``amigo-pi``)."""
    if not name.startswith("classical-"):
        return None
    rule = name.removeprefix("classical-")
    for suffix in ("-robust", "-fixed"):
        rule = rule.removesuffix(suffix)
    return rule


def _cost(row: dict[str, Any]) -> float:
    """The row's mean cost; ``inf`` for a row whose runs diverged (written as ``null``)."""
    cost = row["metrics"]["actual"]["mean"]["cost"]
    return math.inf if cost is None else float(cost)


def _test(a: list[float], b: list[float]) -> dict[str, Any]:
    diff, p = paired_test(a, b)
    verdict = "n.s." if p >= ALPHA else ("better" if diff < 0 else "worse")
    return {"mean_cost_difference": diff, "p_value": p, "verdict": verdict}


def _holm(tests: dict[str, dict[str, Any]]) -> None:
    """Holm-adjust a family of tests in place (``p_holm``) and take the verdict from it."""
    names = list(tests)
    for name, p in zip(names, holm([tests[n]["p_value"] for n in names]), strict=True):
        t = tests[name]
        t["p_holm"] = p
        t["verdict"] = "n.s." if p >= ALPHA else ("better" if t["mean_cost_difference"] < 0
                                                   else "worse")  # fmt: skip


def _to_limit(plant: dict[str, Any], iae: float | None) -> float | None:
    """The share of the gap from command = reference's IAE to the limit's a row closes."""
    refs = plant.get("references") or {}
    limit, reference = refs.get("limit"), refs.get("command=reference")
    if limit is None or reference is None or iae is None or not math.isfinite(iae):
        return None
    ref_iae = reference["metrics"]["actual"]["mean"]["iae"]
    if ref_iae <= limit["iae"]:
        return None
    return (ref_iae - iae) / (ref_iae - limit["iae"])


def _step_os(row: dict[str, Any]) -> float | None:
    """The worse of grip and un-grip step overshoot (first rise, %, mean over the seeds)."""
    m = row["metrics"]["actual"]["mean"]
    values = [m[k].get("step_overshoot_pct") for k in ("grip", "ungrip")]
    return None if any(v is None for v in values) else max(values)


def _hunting(row: dict[str, Any]) -> float | None:
    """Hunting late in the holds: peak-to-peak swing (deg, mean over the seeds)."""
    return row["metrics"]["actual"]["mean"].get("oscillation_deg")


def _clearance(row: dict[str, Any]) -> float | None:
    """How close the jaw came to the nearest stop the preset can draw (deg, worst run)."""
    return ((row.get("admission") or {}).get("measured") or {}).get("clearance_deg")


def _per_plant(pdata: dict[str, Any]) -> dict[str, Any]:
    rows = pdata["rows"]
    reasons = {}
    for name, r in rows.items():
        reasons[name] = ("reference (shown, not ranked)" if r["kind"] not in RANKED_KINDS
                         else why_not_deployable(r))  # fmt: skip
    ranked = sorted((n for n, w in reasons.items() if w is None), key=lambda n: _cost(rows[n]))
    baselines = [n for n in ranked if rows[n]["kind"] == "baseline"]
    best = baselines[0] if baselines else None
    reference = pdata["references"]["command=reference"]
    tests: dict[str, dict[str, Any]] = {}
    family: dict[str, dict[str, Any]] = {}
    for name in ranked:
        tests[name] = {"command=reference": _test(rows[name]["per_seed_cost"],
                                                  reference["per_seed_cost"])}  # fmt: skip
        if best is not None and name != best:
            family[name] = tests[name][best] = _test(rows[name]["per_seed_cost"],
                                                     rows[best]["per_seed_cost"])  # fmt: skip
    _holm(family)  # every ranked row against the best textbook one: one family of tests
    return {"ranked": ranked, "not_ranked": {n: w for n, w in reasons.items() if w},
            "best_baseline": best, "tests": tests}  # fmt: skip


def _entry(key: str, per: dict[str, Any], data: dict[str, Any], plants: list[str]) -> dict:
    """A candidate's headline entry: its figures over the plants (means, and worst cases)."""
    rows = [per[p] for p in plants]
    first = rows[0]
    name = key.split(" @ ")[0]
    # the tuning record is kept with the plant it was tuned on (stored()): any row's
    tuning: dict[str, Any] = next((r["tuning"] for r in per.values() if r.get("tuning")), {})
    knob = tuning.get("knob")
    shares = [_to_limit(data["plants"][p], per[p]["metrics"]["actual"]["mean"]["iae"])
              for p in plants]  # fmt: skip
    return {
        "row": name,
        "family": family_of(name),
        "rule": rule_of(name),
        "knob": None if not knob else {"name": knob["name"], "value": knob["value"],
                                       "meaning": knob.get("meaning", ""),
                                       "design_model": tuning.get("design_model")},
        "tuned_on": first["tuned_on"],
        "kind": first["kind"],
        "sign": None if key == BARE else first.get("sign", 1),
        "cost": float(np.mean([_cost(r) for r in rows])),
        "iae": float(np.mean([r["metrics"]["actual"]["mean"]["iae"] for r in rows])),
        "to_limit": None if None in shares else float(np.mean([float(x or 0.0) for x in shares])),
        "per_plant_cost": {p: _cost(per[p]) for p in plants},
        "per_seed_cost": [c for r in rows for c in r["per_seed_cost"]],
        "worst_step_overshoot_pct": _worst([_step_os(r) for r in rows], max),
        "worst_hunting_deg": _worst([_hunting(r) for r in rows], max),
        "closest_to_stop_deg": _worst([_clearance(r) for r in rows], min),
        "worst_ms": _worst([r["robustness"].get("ms") for r in rows], max),
        "worst_gm_db": _worst([r["robustness"].get("gain_margin_db") for r in rows], min),
        # no margin measured (the bare servo: no loop to probe) is none, not an infinite one
        "worst_measured_gm_db": None if all(r.get("measured_margins") is None for r in rows)
        else _worst([(r.get("measured_margins") or {}).get("gain_margin_db") for r in rows], min),
        "episodes": int(first["episodes"]),
        "P": first["P"], "I": first["I"], "D": first["D"],
    }  # fmt: skip


def _bare_servo(data: dict[str, Any], plants: list[str]) -> dict[str, Any] | None:
    """The bare servo's row on every plant (its reference rows), or ``None``."""
    per = {}
    for p in plants:
        ref = ((data["plants"].get(p) or {}).get("references") or {}).get(BARE)
        if ref is None:
            return None
        per[p] = ref
    return per


def tie_ranks(order: list[str], vs_best: dict[str, dict[str, Any]]) -> tuple[list[str], dict]:
    """The headline's ranks: ``order`` (by cost, the best first) and each row's Holm-corrected
    test against the best (``vs_best``: ``verdict`` ``n.s.``, ``better`` or ``worse``). The
    rows whose difference to the best is not significant share rank 1 (``"1 (tie)"``, the best
    too); the others follow by cost. Returns the rows in rank order and each row's rank."""
    if not order:
        return [], {}
    tied = [order[0], *(k for k in order[1:] if vs_best[k]["verdict"] == "n.s.")]
    rest = [k for k in order if k not in tied]
    word = "1 (tie)" if len(tied) > 1 else "1"
    ranks = {k: word for k in tied}
    ranks.update({k: str(len(tied) + i + 1) for i, k in enumerate(rest)})
    return tied + rest, ranks


def _headline(data: dict[str, Any]) -> dict[str, Any]:
    plants = [p for p in data["robust_plants"] if data["plants"].get(p, {}).get("feasible")]
    admitted, refused = [], {}
    candidates: dict[str, dict[str, Any]] = {}
    bare = _bare_servo(data, plants)
    if bare is not None:
        candidates[BARE] = bare
    candidates.update(data.get("evaluations", {}))
    for key, per in candidates.items():
        if key != BARE and next(iter(per.values()))["kind"] not in RANKED_KINDS:
            continue  # a reference row: shown in its plant's table, never ranked
        if set(per) != set(plants):
            refused[key] = "not evaluated on every identification"
            continue
        reason = None
        for p in plants:
            why = why_not_deployable(per[p])
            if why is not None:
                reason = f"on {p}: {why}"
                break
        if reason:
            refused[key] = reason
            continue
        admitted.append(key)
    for key, why in (data.get("no_result") or {}).items():
        refused[key] = f"no result: {why}"
    entries = {key: _entry(key, candidates[key], data, plants) for key in admitted}
    order = sorted(entries, key=lambda k: entries[k]["cost"])
    # the headline: the best admitted gain set of each family, every textbook rule on its own
    picks: dict[tuple[str, ...], str] = {}
    for k in order:
        e = entries[k]
        slot = ("textbook", e["rule"] or "") if e["family"] == "textbook" else (e["family"],)
        picks.setdefault(slot, k)
    head = sorted(picks.values(), key=lambda k: entries[k]["cost"])
    baselines = [k for k in order if entries[k]["kind"] == "baseline"]
    best = baselines[0] if baselines else None
    top = head[0] if head else None
    bare_costs = (None if bare is None or set(bare) != set(plants)
                  else [c for p in plants for c in bare[p]["per_seed_cost"]])  # fmt: skip
    family: dict[str, dict[str, Any]] = {}
    vs_bare: dict[str, dict[str, Any]] = {}
    vs_top: dict[str, dict[str, Any]] = {}
    for k in order:
        e = entries[k]
        if best is not None and k != best:
            e["vs_best_baseline"] = _test(e["per_seed_cost"], entries[best]["per_seed_cost"])
            if k in head:
                family[k] = e["vs_best_baseline"]
        if bare_costs is not None and k != BARE:
            e["vs_bare_servo"] = _test(e["per_seed_cost"], bare_costs)
            if k in head:
                vs_bare[k] = e["vs_bare_servo"]
        if top is not None and k != top:
            e["vs_best"] = _test(e["per_seed_cost"], entries[top]["per_seed_cost"])
            if k in head:
                vs_top[k] = e["vs_best"]
    # each column one family of tests over the headline's rows, Holm-corrected
    _holm(family)
    _holm(vs_bare)
    _holm(vs_top)
    head, ranks = tie_ranks(head, vs_top)
    return {"plants": plants, "order": order, "head": head, "ranks": ranks, "entries": entries,
            "best_baseline": best, "best": top, "bare_servo": BARE if bare is not None else None,
            "holm_family": list(family), "holm_family_bare_servo": list(vs_bare),
            "holm_family_best": list(vs_top), "not_admitted": refused}  # fmt: skip


def _worst(values: list[Any], pick: Any) -> float | None:
    vals = [math.inf if v is None else float(v) for v in values]
    return pick(vals) if vals else None


def rank(data: dict[str, Any]) -> dict[str, Any]:
    """The verdict: per plant (tuned for one identification) and the headline (one gain set
    for the gripper)."""
    per_plant = {p: _per_plant(d) for p, d in data["plants"].items() if d.get("feasible")}
    return {"per_plant": per_plant, "headline": _headline(data)}


# ----------------------------------------------------------------------------------------------
# Report


def _name(key: str) -> str:
    if key == BARE:
        return BARE_LABEL
    row, _, on = key.partition(" @ ")
    return f"{row} (tuned on {on})" if on else row


def _sign(sign: int | None) -> str:
    if sign is None:  # no host loop, no error
        return "-"
    return "e = r - y" if sign >= 0 else "e = y - r"


def _knob(e: dict[str, Any]) -> str:
    k = e.get("knob")
    if not k:
        return "-"
    model = f", designed on {k['design_model']}" if k.get("design_model") else ""
    return f"{k['meaning'] or k['name']} = {_f(k['value'])}{model}"


def _vs(e: dict[str, Any], key: str, best: str | None, test: str = "vs_best_baseline",
        itself: str = "best textbook") -> str:  # fmt: skip
    if key == best:
        return itself
    t = e.get(test)
    if not t:
        return "-"
    p = t.get("p_holm", t["p_value"])
    return f"{t['verdict']} ({t['mean_cost_difference']:+.3g}, p = {p:.2g})"


def _pct(x: float | None) -> str:
    return "-" if x is None else f"{100 * x:.0f} %"


def _linear(e: dict[str, Any], key: str) -> str:
    """A linear margin of a headline entry; ``-`` for a learned controller (a policy has no
    loop transfer function: its measured limit-cycle onset is the column after)."""
    x = e.get(key)
    return "-" if x is None or not math.isfinite(x) else _f(x)


def render_head(data: dict[str, Any]) -> str:
    """The headline table (the report's and the README's head): the best admitted gain set
    of each family, every textbook rule with its knob."""
    h = data["leaderboard"]["headline"]
    plants = ", ".join(h["plants"])
    lines = [
        f"| rank | family | gain set | error sign | P | I | D | knob | cost (mean over {plants}) "
        "| IAE deg·s | to limit | step OS % | worst Ms (hold) | worst GM dB (hold) | "
        "limit-cycle onset dB | closest to a stop deg | vs bare servo (cost, Holm p) | "
        "vs best textbook (cost, Holm p) |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    ranks = h.get("ranks") or {}
    for i, key in enumerate(h.get("head", h["order"])):
        e = h["entries"][key]
        lines.append(
            f"| {ranks.get(key, i + 1)} | {e.get('family', '-')} | {_name(key)} | "
            f"{_sign(e.get('sign'))} | "
            f"{_f(e['P'], 4)} | {_f(e['I'], 4)} | {_f(e['D'], 3)} | {_knob(e)} | "
            f"{_f(e['cost'], 4)} | {_f(e['iae'], 4)} | {_pct(e.get('to_limit'))} | "
            f"{_f(e.get('worst_step_overshoot_pct'))} | {_linear(e, 'worst_ms')} | "
            f"{_linear(e, 'worst_gm_db')} | {_f(e['worst_measured_gm_db'])} | "
            f"{_f(e.get('closest_to_stop_deg'))} | "
            f"{_vs(e, key, h.get('bare_servo'), 'vs_bare_servo', 'itself')} | "
            f"{_vs(e, key, h['best_baseline'])} |"
        )
    return "\n".join(lines)


def _plant_table(
    plant: str, pdata: dict[str, Any], info: dict[str, Any], meta: dict[str, Any] | None = None
) -> list[str]:
    refs = pdata["references"]
    rows = pdata["rows"]
    base = info["best_baseline"]
    limit = refs.get("limit")
    ref_iae = refs["command=reference"]["metrics"]["actual"]["mean"]["iae"]

    def frac(iae: float | None) -> str:
        return _pct(_to_limit(pdata, iae))

    lines = [
        "",
        f"### {plant}: tuned for this identification",
        "",
        f"Best textbook design (knob set under the admission rule): `{base}`. Limit: IAE "
        + (f"{limit['iae']:.4g} deg·s" if limit else "not computed")
        + f"; command = reference: IAE {ref_iae:.4g} deg·s. **to limit** = the share of that "
        "gap a row closes. " + _band_words(meta),
        "",
        "| rank | row | P | I | D | cost | IAE deg·s | to limit | step OS % (grip / un-grip) | "
        "hunting p-p deg | closest to a stop deg | Ms | GM dB | limit-cycle onset dB | "
        "delay margin ms | vs best textbook (cost, Holm p) | episodes |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    order = info["ranked"] + [n for n in rows if n not in info["ranked"]]
    for name in order:
        r = rows[name]
        a = r["metrics"]["actual"]
        rb = r["robustness"]
        unstable = rb.get("linear", True) and not rb.get("stable", True)
        mm = r.get("measured_margins") or {}
        test = info["tests"].get(name, {}).get(base) if base else None
        vs = (f"{test['verdict']} ({test['mean_cost_difference']:+.3g}, "
              f"p = {test.get('p_holm', test['p_value']):.2g})"
              if test else ("-" if name != base else "(itself)"))  # fmt: skip
        rank = str(info["ranked"].index(name) + 1) if name in info["ranked"] else "-"
        margins = (
            f"ρ = {_f(rb.get('max_pole_magnitude'))} | - | - | - |"
            if unstable
            else f"{_f(rb.get('ms'))} | {_f(rb.get('gain_margin_db'))} | "
            f"{_f(mm.get('gain_margin_db'))} | "
            f"{_f(None if mm.get('delay_margin_s') is None else 1e3 * mm['delay_margin_s'])} |"
        )
        m = a["mean"]
        lines.append(
            f"| {rank} | {name} | {_f(r['P'], 4)} | {_f(r['I'], 4)} | {_f(r['D'], 3)} | "
            f"{_ci(a, 'cost')} | {_ci(a, 'iae')} | {frac(m['iae'])} | "
            f"{_f(m['grip'].get('step_overshoot_pct'))} / "
            f"{_f(m['ungrip'].get('step_overshoot_pct'))} | {_f(_hunting(r))} | "
            f"{_f(_clearance(r))} | {margins} {vs} | {r['episodes']} |"
        )
    lines += ["", "Reference rows (never ranked):", ""]
    for name in ("command=reference", "oracle", "oracle-preview"):
        if name in refs:
            ref = refs[name]
            m = ref["metrics"]["actual"]["mean"]
            adm = ref.get("admission")
            rule = (
                ""
                if not adm
                else (
                    "; meets the admission rule's run part (settled, no stall, inside the stops)"
                    if adm["admitted"]
                    else f"; misses the admission rule's run part: {adm['reason']}"
                )
            )
            lines.append(f"* `{name}`: cost {_f(m['cost'], 4)}, IAE {_f(m['iae'], 4)} deg·s "
                         f"({frac(m['iae'])} of the way to the limit) - "
                         f"{ref['controller']}{rule}")  # fmt: skip
    if limit:
        lines.append(f"* `limit`: IAE {limit['iae']:.4g} deg·s - {limit['controller']} on the "
                     f"{limit['model']}")  # fmt: skip
    if info["not_ranked"]:
        lines += ["", "Not ranked:"]
        lines += [f"* `{n}`: {why}" for n, why in info["not_ranked"].items()]
    return lines


def _head_notes() -> str:
    """The headline's columns that need words: the rank, the two tests and to limit."""
    return (
        "**rank**: every row is tested against the row of least mean cost, paired over the "
        "(plant, held-out seed) runs (two-sided Wilcoxon signed-rank test, Holm-corrected over "
        f"the table); the rows whose difference is not significant (p >= {ALPHA:g}) share rank "
        '1, marked "1 (tie)", and the others follow by cost. **vs bare servo** and **vs best '
        "textbook**: a row's mean cost difference to that row over the same runs, paired, and its "
        "Holm-corrected p (each column one family of tests); better or worse only where p < "
        f"{ALPHA:g}, n.s. otherwise. **to limit**: the share of the gap from the bare servo's "
        "IAE (0 %) to the limit's (100 %: the least IAE any command sequence reaches, a linear "
        "program on the ideal model) that a row closes, mean over the plants; a negative value is "
        "an IAE larger than the bare servo's: tracking worse than no host loop at all."
    )


def _band_words(meta: dict[str, Any] | None) -> str:
    """The settling band and the stop rule, in words, for every table that uses them."""
    if not meta or "settling_band_deg" not in meta:
        return ""
    band = meta["settling_band_deg"]
    return (f"Settling band: max(2 % of the move, the preset's friction band {band:.3g} deg) = "
            f"{max(band, 0.02 * 71.0):.3g} deg on the 71 deg grip and un-grip; **step OS** = "
            "overshoot of the first rise only (until the jaw first comes to rest), **hunting** = "
            "the peak-to-peak swing over the last 2 s of the holds (friction stick-slip), "
            "**closest to a stop** = the jaw's nearest approach, over every held-out run, to the "
            "nearest stop the preset can draw.")  # fmt: skip


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


def _margin_check(data: dict[str, Any]) -> list[str]:
    """Measured against linear gain margins of every stable PID row: the probe's validation."""
    pairs = []
    for plant, pdata in data["plants"].items():
        for name, r in (pdata.get("rows") or {}).items():
            rb, mm = r["robustness"], r.get("measured_margins") or {}
            if r.get("controller") != "pid" or not rb.get("stable"):
                continue
            lin, meas = rb.get("gain_margin_db"), mm.get("gain_margin_db")
            if lin is not None and meas is not None:
                pairs.append((plant, name, lin, meas))
    if not pairs:
        return []
    diffs = np.array([m - lin for _, _, lin, m in pairs])
    return [
        "",
        "## Measured margins, validated",
        "",
        f"Every stable PID row's gain margin measured by the probe (gain sweep until the "
        f"frictionless loop with the hold swings more than 1 deg) against its linear gain "
        f"margin with the hold: {len(pairs)} rows, difference {diffs.mean():+.3f} dB on "
        f"average, largest {np.abs(diffs).max():.3f} dB. The same probe measures the learned "
        "controllers' margins.",
    ]


def _rule_words(meta: dict[str, Any]) -> str:
    """The admission rule with its numbers, in one paragraph."""
    lim = meta["objective"]["constraints"]
    stops = meta.get("nearest_stops_deg")
    where = (f" (the closed stop is drawn up to {stops[0]:g} deg and the open one down to "
             f"{stops[1]:g} deg: the jaw must stay within {stops[0]:g}-{stops[1]:g} deg on every "
             "run, whichever stop the run drew)" if stops else "")  # fmt: skip
    floor = 20.0 * math.log10(lim["ms_max"] / (lim["ms_max"] - 1.0))
    return (
        "One admission rule (`gripper_env/evaluation/admission.py`), the constraints every search "
        "tuned under and the judge applies to the held-out runs of every identification: the loop "
        f"as it runs (PID at 1 ms, the servo's 20 ms hold) stable with Ms <= {lim['ms_max']:g} and "
        f"GM >= {lim['gm_min_db']:g} dB (a learned controller: its measured limit-cycle onset at "
        f"least the {floor:.3g} dB gain margin that Ms <= {lim['ms_max']:g} guarantees a linear "
        "loop), every run settled, no stall, the jaw at least "
        f"{lim.get('stop_clearance_deg', 0):g} deg inside the nearest stop the preset can draw"
        f"{where}: a worst case over the stop range, not the sampled stops"
        + (
            ", and the grasp scenario's object held on every run (close on an object at 40 deg, "
            "hold 3 s with at least 1 N, no thermal trip of the servo; "
            "`gripper_env/evaluation/grasp.py`)"
            if lim.get("grasp")
            else ""
        )
        + ". The searches hold "
        f"the jaw {lim.get('search_backoff_deg', 0):g} deg further in (they see 4 friction and "
        "noise draws, the judge 10 others)."
    )


def render_markdown(data: dict[str, Any], meta: dict[str, Any]) -> str:
    """The benchmark report (Markdown)."""
    lb = data["leaderboard"]
    h = lb["headline"]
    obj = meta["objective"]
    lines = [
        "# Benchmark: PID tuners and learned controllers for the hobby-servo gripper",
        "",
        f"Generated by `{meta['command']}`{_reruns(meta)}. Profile `{meta['profile']}` (grip "
        "step 92 -> 21 deg at 1 s, un-grip at 10 s, 20 s), actual-gripper preset "
        f"`{meta['disturbance']}` "
        f"(stops beyond 21 and 92 deg, so overshoot is visible), {meta['n_seeds']} held-out "
        "seeds. Provenance (commit, date, version, machine, wall times): "
        "`benchmark.provenance.json`.",
        "",
        "## Headline: the best deployable gain set of each family",
        "",
        _rule_words(meta) + f" Admitted only if it meets the rule on every identification "
        f"({', '.join(h['plants'])}); test1 is left out: it cannot follow the step profile "
        "within the servo's range (below). One row per family (each textbook rule with its knob "
        "set under the rule and its design model chosen, the best admitted of it), and the "
        "**bare servo** (command = reference: the servo's own position loop, no host loop), "
        "scored and judged like every row (its loop is open: Ms 1, no gain margin to miss). An "
        "RL controller's P, I, D are the PID its policy corrects (the base); it has no linear Ms "
        "or GM (-), its measured limit-cycle onset is judged instead. "
        + _head_notes()
        + " "
        + _band_words(meta),
        "",
        render_head(data),
        "",
    ]
    lines += _verdict_words(data)
    lines += _admitted_table(data)
    if h["not_admitted"]:
        lines += ["", "Not admitted:", ""]
        lines += [f"* {_name(k)}: {why}" for k, why in h["not_admitted"].items()]
    lines += _stress_section(data)
    lines += _moved_section(data)
    lines += ["", "## Tuned for one identification"]
    for plant, pdata in data["plants"].items():
        if not pdata.get("feasible"):
            lines += ["", f"### {plant}", "", f"**Not ranked.** {plant}: {pdata['reason']}."]
            continue
        lines += _plant_table(plant, pdata, lb["per_plant"][plant], meta)
    lines += _rl_section(data)
    lines += _margin_check(data)
    if data.get("grasp"):
        from tuners.benchmark.grasp import benchmark_section

        lines += benchmark_section(data["grasp"])
    lines += [
        "",
        "## How to read it",
        "",
        "* Ranked by the objective's cost on the actual model (`configs/objective.yaml`: "
        + ", ".join(f"{k} {v:g}" for k, v in obj["weights"].items() if v)
        + "), the cost every search minimises, under the admission rule as constraints; IAE "
        "beside it. The cost's overshoot term is the largest excursion past the target anywhere "
        "in the hold (late hunting included); the tables' **step OS** is the first rise's alone.",
        "* **vs best textbook**: paired Wilcoxon signed-rank test of the per-seed costs against "
        "the best admitted textbook row (a rule with its knob set under the same rule), "
        f"two-sided, Holm-corrected over each table's tests, p < {ALPHA} for a verdict.",
        "* **limit-cycle onset**: how far (dB) the plant's gain can rise before the loop, made "
        "frictionless with the servo's hold, swings on its own (`tuners/probe.py`). For a PID it "
        "is the linear gain margin (section above); for a learned controller, the only margin "
        "it has, and not a gain margin: its loop is not linear.",
        "* **to limit**: the share of the gap from command = reference's IAE (the bare servo, "
        "0 %) to the limit's (the least IAE any command sequence reaches, 100 %) a row closes, "
        "mean over the plants; negative: a larger IAE than the bare servo's, tracking worse than "
        "no host loop.",
        "* `*-fixed`: a textbook rule at its fixed setting (e.g. SIMC's tau_c = theta), shown "
        "for reference.",
        "",
        "Figures: `figures/benchmark_pareto.png` (tracking against robustness: every row, the "
        "MIGO front, the limit and the oracle), `figures/benchmark_budget_<plant>.png` (best "
        "tuning cost against simulated episodes), each row's response plot `<plant>/<row>.png` "
        "(not committed; `python -m tuners.manual --plant <plant> --gains <plant>/<row>.json` "
        "draws it from the gains file).",
        "",
    ]
    return "\n".join(lines)


def _reruns(meta: dict[str, Any]) -> str:
    """The rows run again since (``--rerun``), with their commands, in words."""
    parts = [f"`{r['command']}` ({', '.join(r['rows'])})" for r in meta.get("reruns") or []]
    if not parts:
        return ""
    return (", then these rows run again over its stored per-seed results, every other row "
            "kept as stored: " + "; ".join(parts))  # fmt: skip


def _admitted_table(data: dict[str, Any]) -> list[str]:
    """Every admitted gain set, ranked (the headline keeps the best of each family)."""
    h = data["leaderboard"]["headline"]
    if len(h["order"]) <= len(h.get("head", [])):
        return []
    lines = ["", f"Every admitted gain set ({len(h['order'])}), ranked:", "",
             "| rank | gain set | cost | IAE deg·s | step OS % | hunting p-p deg | "
             "closest to a stop deg | worst Ms | P | I | D |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]  # fmt: skip
    for i, key in enumerate(h["order"]):
        e = h["entries"][key]
        lines.append(f"| {i + 1} | {_name(key)} | {_f(e['cost'], 4)} | {_f(e['iae'], 4)} | "
                     f"{_f(e.get('worst_step_overshoot_pct'))} | "
                     f"{_f(e.get('worst_hunting_deg'))} | {_f(e.get('closest_to_stop_deg'))} | "
                     f"{_f(e['worst_ms'])} | {_f(e['P'], 4)} | {_f(e['I'], 4)} | "
                     f"{_f(e['D'], 3)} |")  # fmt: skip
    return lines


def _stress_section(data: dict[str, Any]) -> list[str]:
    """Every candidate on the extra held-out seeds: runs touching a stop, closest approach."""
    st = data.get("stress")
    if not st or not st.get("rows"):
        return []
    h = data["leaderboard"]["headline"]
    admitted = set(h["order"])
    seeds = st["seeds"]
    rows = st["rows"]
    touch_admitted = [k for k in admitted if (rows.get(k) or {}).get("contact_runs")]
    lines = ["", f"## Stop contact on {len(seeds)} more held-out {st['plant']} seeds", "",
             f"Seeds {seeds[0]}-{seeds[-1]}, disjoint from the tuning, validation and held-out "
             "ones; the stops drawn as in every run. "
             + (f"**{len(touch_admitted)} admitted gain set(s) touch a stop** on them."
                if touch_admitted else "No admitted gain set touches a stop on any of them.")
             + " Candidates refused by the headline are listed too: the rule refused them "
             "for a reason these seeds show.", "",
             "| gain set | admitted | runs touching a stop | jaw min deg | jaw max deg | "
             "closest to a drawable stop deg | cost |",
             "|---|---|---|---|---|---|---|"]  # fmt: skip
    for key in sorted(rows, key=lambda k: (k not in admitted, rows[k]["cost"])):
        r = rows[key]
        lines.append(f"| {_name(key)} | {'yes' if key in admitted else 'no'} | "
                     f"{r['contact_runs']} of {r['runs']} | {_f(r['jaw_min_deg'], 4)} | "
                     f"{_f(r['jaw_max_deg'], 4)} | {_f(r['clearance_deg'])} | "
                     f"{_f(r['cost'], 4)} |")  # fmt: skip
    return lines


def _moved_verdict(sm: dict[str, Any], plants: list[str]) -> dict[str, Any]:
    """The headline's picks under the moved stops: admitted candidates and the best of each
    family (judged rows and the retuned ones)."""
    entries: dict[tuple[str, str], dict[str, Any]] = {}
    for group in ("rows", "retuned"):
        for key, per in (sm.get(group) or {}).items():
            if set(per) != set(plants):
                continue
            if all(per[p]["admission"]["admitted"] for p in plants):
                name = key.split(" @ ")[0]
                entries[(group, key)] = {
                    "family": family_of(name), "rule": rule_of(name),
                    "cost": float(np.mean([per[p]["cost"] for p in plants])),
                    "clearance": _worst([per[p]["admission"]["measured"].get("clearance_deg")
                                         for p in plants], min),
                }  # fmt: skip
    picks: dict[tuple[str, ...], tuple[str, str]] = {}
    for k in sorted(entries, key=lambda k: entries[k]["cost"]):
        e = entries[k]
        slot = ("textbook", e["rule"] or "") if e["family"] == "textbook" else (e["family"],)
        picks.setdefault(slot, k)
    return {"entries": entries, "head": sorted(picks.values(), key=lambda k: entries[k]["cost"])}


def _moved_section(data: dict[str, Any]) -> list[str]:
    """How the verdict moves with the stops further out."""
    sm = data.get("stops_moved")
    if not sm:
        return []
    h = data["leaderboard"]["headline"]
    plants = h["plants"]
    moved = _moved_verdict(sm, plants)
    before = set(h["order"]) - {BARE}  # the bare servo is not judged again there
    after = {k for g, k in moved["entries"] if g == "rows"}
    gained = sorted(after - before)
    lost = sorted(before - after)
    lines = ["", f"## Sensitivity: the stops {sm['shift_deg']:g} deg further out", "",
             "Where the stops lie is the preset's assumption (the paper does not say). With both "
             f"stops and their ranges {sm['shift_deg']:g} deg further out (stops at "
             f"{', '.join(f'{x:g}' for x in sm['limits_deg'])} deg, drawn in "
             + ", ".join(f"{a:g}-{b:g}" for a, b in sm["randomize"].values())
             + " deg), every candidate is judged again on the held-out seeds, and the robust "
             "searches and textbook rules are tuned again under the moved stops (RL rows judged, "
             f"not retrained). Admitted then: {len(after)} of the candidates (now {len(before)})"
             + (f"; newly admitted: {', '.join(_name(k) for k in gained)}" if gained else "")
             + (f"; no longer admitted: {', '.join(_name(k) for k in lost)}" if lost else "")
             + ".", "",
             "| family | gain set | cost (now) | cost (stops moved) | closest to a stop deg "
             "(stops moved) |", "|---|---|---|---|---|"]  # fmt: skip
    for group, key in moved["head"]:
        e = moved["entries"][(group, key)]
        now = h["entries"].get(key, {}).get("cost") if group == "rows" else None
        label = _name(key) + (" (tuned again)" if group == "retuned" else "")
        lines.append(f"| {e['family']} | {label} | {_f(now, 4)} | {_f(e['cost'], 4)} | "
                     f"{_f(e['clearance'])} |")  # fmt: skip
    for key, per in (sm.get("retuned") or {}).items():
        g = next(iter(per.values()))
        lines.append("")
        lines.append(f"* {_name(key)} tuned again with the stops moved: P = {_f(g['P'], 4)}, "
                     f"I = {_f(g['I'], 4)}, D = {_f(g['D'], 3)}, tuning cost "
                     f"{_f(g.get('tuning_cost'), 4)}, held-out cost "
                     f"{_f(float(np.mean([v['cost'] for v in per.values()])), 4)}.")  # fmt: skip
    return lines


_WORDS = {
    "better": "beats {what} significantly",
    "worse": "is significantly worse than {what}",
    "n.s.": "does not differ significantly from {what}",
}


def _said(t: dict[str, Any], what: str) -> str:
    """A test in words: the verdict, the cost difference and the Holm p."""
    return (_WORDS[t["verdict"]].format(what=what)
            + f" (cost {t['mean_cost_difference']:+.3g}, Holm p = "
            f"{t.get('p_holm', t['p_value']):.2g})")  # fmt: skip


def _verdict_words(data: dict[str, Any]) -> list[str]:
    """What a reader should take away, in words, computed from the tests (never "best" for a
    row that ties): the rank-1 rows; each family against the bare servo and against the
    lowest-cost textbook row; per plant, the searches against the lowest-cost textbook design."""
    lb = data["leaderboard"]
    h = lb["headline"]
    out = []
    head = h.get("head", [])
    ranks = h.get("ranks") or {}
    best = h["best_baseline"]
    top = h.get("best", head[0] if head else None)
    if top is not None:
        e = h["entries"][top]
        figures = (f"cost {e['cost']:.4g}, IAE {e['iae']:.4g} deg·s"
                   + (f", {100 * e['to_limit']:.0f} % of the way to the limit"
                      if e.get("to_limit") is not None else ""))  # fmt: skip
        tied = [k for k in head if k != top and ranks.get(k) == ranks.get(top)]
        if tied:
            others = "; ".join(
                f"`{_name(k)}` (cost {h['entries'][k]['cost']:.4g}, "
                f"{h['entries'][k]['vs_best']['mean_cost_difference']:+.3g}, Holm p = "
                f"{h['entries'][k]['vs_best'].get('p_holm', 1.0):.2g})"
                for k in tied
            )
            out.append(f"* **No single best gain set for the gripper:** `{_name(top)}` has the "
                       f"least mean cost ({figures}), but {len(tied)} row(s) do not differ from "
                       f"it significantly and share rank 1: {others}.")  # fmt: skip
        else:
            out.append(f"* **Best deployable gain set for the gripper:** `{_name(top)}` "
                       f"({figures}), significantly better than every other row of the "
                       "headline.")  # fmt: skip
    bare = h.get("bare_servo")
    if bare is not None:
        if bare in h["entries"]:
            e = h["entries"][bare]
            out.append(f"* **The bare servo** (command = reference, no host loop) is admitted: "
                       f"cost {e['cost']:.4g}, IAE {e['iae']:.4g} deg·s, rank "
                       f"{ranks.get(bare, '-')}.")  # fmt: skip
        else:
            why = h["not_admitted"].get(bare, "")
            out.append(f"* **The bare servo** (command = reference, no host loop) is not "
                       f"admitted: {why}.")  # fmt: skip
    if best is not None:
        b = h["entries"][best]
        out.append(f"* **Textbook design of least cost:** `{_name(best)}` ({_knob(b)}; cost "
                   f"{b['cost']:.4g}).")  # fmt: skip
    for family, label in (
        ("textbook", "The textbook design"),
        ("optuna", "Optuna"),
        ("rl-tune", "The RL PID tuner"),
        ("rl-controller", "The RL controller"),
        ("manual", "The paper's gains"),
    ):
        keys = [k for k in head if h["entries"][k]["family"] == family]
        if not keys:
            if family != "textbook":
                out.append(f"* {label}: no admitted row.")
            continue
        key = best if family == "textbook" and best in keys else min(
            keys, key=lambda k: h["entries"][k]["cost"])  # fmt: skip
        e = h["entries"][key]
        parts = []
        if e.get("vs_bare_servo") is not None:
            parts.append(_said(e["vs_bare_servo"], "the bare servo"))
        if e.get("vs_best_baseline") is not None:
            parts.append(_said(e["vs_best_baseline"], "the textbook design of least cost"))
        if not parts:
            continue
        out.append(f"* {label} (`{_name(key)}`, cost {e['cost']:.4g}) " + "; it ".join(parts)
                   + ".")  # fmt: skip
    for plant, info in lb["per_plant"].items():
        base = info["best_baseline"]
        for name in ("optuna", "rl-tune", "rl-controller"):
            if name not in info["ranked"] or base is None:
                continue
            t = info["tests"][name].get(base)
            if t is None:
                continue
            out.append(
                f"* {plant}, tuned for it alone: `{name}` "
                + _said(t, f"the textbook design of least cost `{base}`")
                + "."
            )
    return ["In words (computed from the tables):", "", *out] if out else []


def _rl_rows(data: dict[str, Any]) -> list[tuple[str, dict[str, Any], Any, dict[str, Any]]]:
    """``(where, row, optuna row or None, {plant: row})`` of every RL row: per plant, and the
    robust ones (``row`` from their first plant's evaluation, every plant's in the dict)."""
    out = []
    for plant, pdata in data["plants"].items():
        for name in ("rl-tune", "rl-controller"):
            if name in (pdata.get("rows") or {}):
                row = pdata["rows"][name]
                out.append((plant, row, pdata["rows"].get("optuna"), {plant: row}))
    for key, per in (data.get("evaluations") or {}).items():
        name, _, on = key.partition(" @ ")
        if name in ("rl-tune-robust", "rl-controller-robust") and per:
            optuna = next((v for k, v in data["evaluations"].items()
                           if k.startswith("optuna-robust @")), None)  # fmt: skip
            first = next(iter(per.values()))
            out.append((on, first, None if optuna is None else next(iter(optuna.values())), per))
    return out


def _optuna_cost(data: dict[str, Any], per_plant: dict[str, Any]) -> float | None:
    """Optuna's held-out cost on the same plants as an RL row: its per-plant row's, or for a
    robust row the robust Optuna row's mean over the plants (as the RL row's is)."""
    if len(per_plant) == 1:
        (plant,) = per_plant
        row = (data["plants"][plant].get("rows") or {}).get("optuna")
        return None if row is None else float(row["metrics"]["actual"]["mean"]["cost"])
    per = next((v for k, v in (data.get("evaluations") or {}).items()
                if k.startswith("optuna-robust @")), None)  # fmt: skip
    if not per or set(per) != set(per_plant):
        return None
    costs = [r["metrics"]["actual"]["mean"]["cost"] for r in per.values()]
    return None if any(c is None for c in costs) else float(np.mean(costs))


def _worst_margins(rows: dict[str, dict[str, Any]], seed: str) -> tuple[Any, Any, str]:
    """A training seed's smallest measured gain margin (dB) and delay margin (s) over the
    plants it is evaluated on, and the plant of the smallest gain margin."""
    found = [(p, r["measured_margins"]["per_seed"][seed]) for p, r in rows.items()
             if seed in ((r.get("measured_margins") or {}).get("per_seed") or {})]  # fmt: skip
    gms = [(m["gain_margin_db"], p) for p, m in found if m["gain_margin_db"] is not None]
    delays = [m["delay_margin_s"] for _, m in found if m["delay_margin_s"] is not None]
    gm, plant = min(gms) if gms else (None, "")
    return gm, (min(delays) if delays else None), plant


def figures(data: dict[str, Any], out: Path) -> list[Path]:
    """The Pareto figure, the budget curves and the RL learning curves (mean and band over the
    training seeds, against Optuna's best or the base PID)."""
    from tuners.plotting import budget_plot, learning_curve_plot, pareto_plot

    paths = [pareto_plot(data, out / "figures" / "benchmark_pareto.png")]
    for plant, pdata in data["plants"].items():
        if pdata.get("feasible") and pdata.get("curves"):
            paths.append(budget_plot(
                pdata["curves"], f"{plant}: best feasible tuning cost vs simulated episodes",
                out / "figures" / f"benchmark_budget_{plant}.png",
            ))  # fmt: skip
    for where, row, optuna, _ in _rl_rows(data):
        t = row["tuning"]
        if row["kind"] == "search" and t.get("curves"):
            curves = [([p[0] for p in c], [math.nan if p[1] is None else p[1] for p in c])
                      for c in t["curves"].values()]  # fmt: skip
            lines = {}
            if optuna is not None:
                lines["Optuna (TPE) best tuning cost"] = optuna["tuning"]["best_value_tuning"]
            paths.append(learning_curve_plot(
                curves, out / "figures" / f"rl_tune_{where}.png",
                f"{where}: RL PID tuner, the policy's gains on the tuning seeds "
                f"({len(curves)} seeds)", "training episodes", "tuning cost", lines=lines,
                labels=[f"seed {k}" for k in t["curves"]],
            ))  # fmt: skip
        elif row["kind"] == "controller" and row.get("learning_curve"):
            c = row["learning_curve"]
            paths.append(learning_curve_plot(
                [(c["steps"], v) for v in c["per_seed"].values()],
                out / "figures" / f"rl_controller_{where}.png",
                f"{where}: RL controller, validation cost ({len(c['per_seed'])} seeds)",
                "training steps (20 ms)", "mean cost, validation seeds",
                lines={"base PID": c["base"]}, labels=[f"seed {k}" for k in c["per_seed"]],
            ))  # fmt: skip
    return paths


def _rl_section(data: dict[str, Any]) -> list[str]:
    """The RL rows as an RL researcher reads them: per training seed, with the spread."""
    lines: list[str] = []
    for where, row, optuna, per_plant in _rl_rows(data):
        t = row["tuning"]
        if row["kind"] == "search":
            ref = _optuna_cost(data, per_plant) if optuna is not None else None
            held = t["held_out_cost"]
            ratio = (
                ""
                if ref is None
                else f" ({100 * (held['median'] / ref - 1):+.1f} % against Optuna's {ref:.4g})"
            )
            lines += ["", f"### RL PID tuner on {where}", "",
                      f"Held-out cost of each seed's exported gains: median {held['median']:.4g}"
                      f"{ratio}, range {held['min']:.4g}-{held['max']:.4g} over {held['n']} "
                      f"seeds. Learning curve: `figures/rl_tune_{where}.png`.", "",
                      "| seed | tuning cost | at episodes | held-out cost | admission rule |",
                      "|---|---|---|---|---|"]  # fmt: skip
            for e in t["per_seed"]:
                verdict = ("met" if e["meets_constraints"] else
                           f"NOT met: {e.get('admission_reason') or 'robustness'}")  # fmt: skip
                lines.append(f"| {e['seed']} | {_f(e['best_value_tuning'], 4)} | "
                             f"{_f(e['at_episodes'])} | {_f(e['held_out_cost'], 4)} | "
                             f"{verdict} |")  # fmt: skip
        elif row["kind"] == "controller":
            c = row["learning_curve"]
            tsc = row["training_seed_cost"]
            mm = row["measured_margins"]
            lines += [
                "",
                f"### RL controller on {where}",
                "",
                f"{len(tsc['per_seed'])} training seeds: held-out cost {tsc['mean']:.4g} "
                f"± {tsc['std']:.3g} (sd over seeds), worst seed {tsc['worst_seed']} at "
                f"{tsc['max']:.4g}. "
                + (
                    f"The mean validation cost first beats the base PID at "
                    f"{_f(c['first_step_mean_beats_base'])} steps. "
                    if c.get("first_step_mean_beats_base") is not None
                    else "The mean validation cost never beats the base PID's in training. "
                )
                + "Learning curve: "
                f"`figures/rl_controller_{where}.png`.",
                f"`figures/rl_controller_{where}.png`.",
                "",
                "| seed | held-out cost | vs base PID | p (Wilcoxon) | better on seeds | "
                "limit-cycle onset dB | delay margin ms |",
                "|---|---|---|---|---|---|---|",
            ]
            for seed, cost in tsc["per_seed"].items():
                d = row["vs_base_per_training_seed"][seed]
                gm, delay_s, on = _worst_margins(per_plant, seed)
                delay = None if delay_s is None else 1e3 * delay_s
                gm_txt = _f(gm) + (f" ({on})" if len(per_plant) > 1 and on else "")
                lines.append(f"| {seed} | {cost:.4g} | {100 * d['cost_relative']:+.2f} % | "
                             f"{d['p_value']:.2g} | {d['better_on_seeds']} | "
                             f"{gm_txt} | {_f(delay)} |")  # fmt: skip
            worst = " (the worst plant's, named)" if len(per_plant) > 1 else ""
            lines.append(f"\nLimit-cycle onset{worst}: the plant's gain rise (dB) at which the "
                         "frictionless loop with the hold starts to swing on its own (the probe, "
                         "`tuners/probe.py`); the admission rule asks for "
                         f"{mm['required_gain_margin_db']:.3g} dB, the gain margin Ms <= 1.6 "
                         "guarantees a linear loop.")  # fmt: skip
            lines += _controller_admission(per_plant, row)
    return ["", "## Reinforcement learning, over training seeds", *lines] if lines else []


def _controller_admission(per_plant: dict[str, Any], row: dict[str, Any]) -> list[str]:
    """A learned controller's verdict plant by plant: admitted or why not, its held-out cost
    against its base PID's, its worst limit-cycle onset beside the base PID's gain margin (the
    linear one with the hold, which the probe measures too)."""
    out = []
    for plant, r in per_plant.items():
        adm = r.get("admission")
        if not adm:
            continue
        word = "admitted" if adm["admitted"] else f"not admitted: {adm['reason']}"
        base = r.get("base") or {}
        own = r["metrics"]["actual"]["mean"]["cost"]
        cmp = (
            ""
            if base.get("cost") is None or own is None
            else f"; held-out cost {own:.4g} against its base PID's {base['cost']:.4g}"
        )
        onset = (r.get("measured_margins") or {}).get("gain_margin_db")
        base_gm = (base.get("measured_margins") or {}).get("gain_margin_db")
        margins = (f"; limit-cycle onset {_f(onset)} dB (worst seed), the base PID's gain "
                   f"margin {_f(base_gm)} dB" if onset is not None or base_gm is not None
                   else "")  # fmt: skip
        out.append(f"* {plant}: {word}{cmp}{margins}.")
    return ["", *out] if out else []


README_START = "<!-- leaderboard:start"
README_END = "<!-- leaderboard:end -->"
VERDICT_START = "<!-- verdict:start"
VERDICT_END = "<!-- verdict:end -->"


def head_of(markdown: str) -> str:
    """The headline table inside a benchmark report."""
    lines = markdown.splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith("| rank |"))
    end = start
    while end < len(lines) and lines[end].startswith("|"):
        end += 1
    return "\n".join(lines[start:end])


def verdict_of(markdown: str) -> str:
    """The "In words" bullets under a benchmark report's headline."""
    lines = markdown.splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith("In words"))
    out = []
    for line in lines[start + 1 :]:
        if line.startswith("* "):
            out.append(line)
        elif out and not line.strip():
            break
    return "\n".join(out)


def _between(text: str, start_mark: str, end_mark: str, block: str, where: Path) -> str:
    if start_mark not in text or end_mark not in text:
        raise ValueError(f"{where}: no '{start_mark} ...' and '{end_mark}' markers")
    start = text.index("\n", text.index(start_mark)) + 1
    end = text.index(end_mark)
    return text[:start] + block + "\n" + text[end:]


def update_readme(readme: Path, report: Path) -> bool:
    """Copy the headline table of ``report`` (``benchmark.md``) between the README's
    leaderboard markers, and its verdict in words between the verdict markers (if the README
    has them).

    Returns whether the README changed.

    Raises
    ------
    ValueError
        The README has no leaderboard markers, or the report no headline table.
    """
    from gripper_env.io.files import write_atomic

    text = readme.read_text()
    markdown = report.read_text()
    try:
        head = head_of(markdown)
    except StopIteration:
        raise ValueError(f"{report}: no headline table ('| rank | ...')") from None
    new = _between(text, README_START, README_END, head, readme)
    if VERDICT_START in new:
        try:
            words = verdict_of(markdown)
        except StopIteration:
            raise ValueError(f"{report}: no verdict ('In words ...')") from None
        new = _between(new, VERDICT_START, VERDICT_END, words, readme)
    if new != text:
        write_atomic(readme, new)
    return new != text


def stored(content: dict[str, Any]) -> dict[str, Any]:
    """What ``benchmark.json`` keeps of the benchmark's data: everything the verdict, the
    report and the figures are computed from (:func:`render_again` draws them from it alone),
    every row's per-seed costs and IAEs, and not what nothing reads and is recorded elsewhere:
    the rows' metrics on the ideal model, their sim-to-real gap and their standard deviations
    over seeds (the 95 % intervals stay; the gains file ``<plant>/<row>.json`` of a tuned row
    has them all), and the tuning record of a gain set's evaluations on the plants after the
    first (the same record for every plant: it is kept with the first)."""
    import copy

    out = copy.deepcopy(content)

    def slim(row: dict[str, Any]) -> None:
        metrics = row.get("metrics")
        if isinstance(metrics, dict):
            metrics.pop("ideal", None)
            metrics.pop("sim_to_real_gap", None)
            if isinstance(metrics.get("actual"), dict):
                metrics["actual"].pop("std", None)

    for pdata in (out.get("plants") or {}).values():
        for group in ("rows", "references"):
            for row in (pdata.get(group) or {}).values():
                slim(row)
    for per in (out.get("evaluations") or {}).values():
        for i, row in enumerate(per.values()):
            slim(row)
            if i:
                row.pop("tuning", None)
    return out


def render_again(folder: Path) -> Path:
    """Rank, draw and write ``benchmark.md`` again from ``folder/benchmark.json`` with this
    code, without rerunning the rows (``benchmark.json`` itself is left as it is)."""
    import json

    from gripper_env.io.files import write_atomic

    content = json.loads((folder / "benchmark.json").read_text())
    meta = content["meta"]
    data = {k: v for k, v in content.items() if k not in ("meta", "budget_episodes")}
    data["leaderboard"] = rank(data)
    figures(data, folder)
    path = folder / "benchmark.md"
    write_atomic(path, render_markdown(data, meta))
    return path


def main(argv: list[str] | None = None) -> int:
    """``python -m tuners.benchmark.leaderboard [REPORT] [--readme README.md]``: print the
    headline of a benchmark report, or copy it into the README."""
    import argparse

    parser = argparse.ArgumentParser(
        prog="python -m tuners.benchmark.leaderboard",
        description="Print the benchmark's headline, or copy it into the README.",
    )
    parser.add_argument("report", nargs="?", default="results/benchmark.md")
    parser.add_argument("--readme", default=None, help="write it between this file's markers")
    parser.add_argument("--render", action="store_true",
                        help="first write REPORT and the figures again from the "
                             "benchmark.json beside it (no rows rerun)")  # fmt: skip
    from tuners.conventions import conform

    args = conform(parser, "tuners.benchmark.leaderboard").parse_args(argv)
    try:
        if args.render:
            render_again(Path(args.report).parent)
            print(f"wrote {args.report} and the figures from benchmark.json")
        if args.readme:
            changed = update_readme(Path(args.readme), Path(args.report))
            print(f"{args.readme}: {'updated' if changed else 'already up to date'}")
        else:
            print(head_of(Path(args.report).read_text()))
    except (OSError, ValueError, StopIteration) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
