"""``campaign --faults all|kind1,kind2``: one fault per run, drawn from the seed, judged
against its expected outcome (:data:`eaglemission.lab.faults.outcomes.OUTCOMES`).

Each block of ``len(kinds)`` runs flies every kind once in a seeded order; the state, delay,
duration and size of each come from the kind's campaign range. A run fails with its reason when
the fault was never injected, when it ends anywhere but the expected outcome (GRASP_READY +
DONE for a tolerable fault, FAILSAFE with the configured safe action, landed, for an
intolerable one), when the true trajectory left the envelope, or when its log is incomplete.
"""

from __future__ import annotations

import json
from typing import Any

import numpy as np
from eaglemission.lab.faults.config import FAULT_KINDS, faults_of
from eaglemission.lab.faults.outcomes import COMPLETE, OUTCOMES, expected_action

from eaglemission.config import MissionFile, TargetConfig

LOG_KINDS = ("start", "config", "state", "end", "evaluation", "fault_injected")
"""Records every fault run's log must hold."""


def parse_kinds(text: str) -> list[str]:
    """``all`` or comma-separated kinds; ValueError naming the unknown ones."""
    if text.strip() == "all":
        return list(FAULT_KINDS)
    kinds = [k.strip() for k in text.split(",") if k.strip()]
    bad = [k for k in kinds if k not in OUTCOMES]
    if bad or not kinds:
        raise ValueError(f"--faults: unknown kind(s) {', '.join(bad) or '(none given)'}; "
                         f"use 'all' or some of: {', '.join(FAULT_KINDS)}")
    return kinds


def draw_fault(kind: str, rng: np.random.RandomState) -> dict[str, Any]:
    """One fault of ``kind`` with its state, delay, duration and size drawn from its range."""
    o = OUTCOMES[kind]
    spec: dict[str, Any] = {
        "kind": kind, "at_state": o.states[int(rng.randint(len(o.states)))],
        "delay_s": round(float(rng.uniform(*o.delay_s)), 3),
        "duration_s": round(float(rng.uniform(*o.duration_s)), 3)}
    if o.size is not None:
        spec["size"] = round(float(rng.uniform(*o.size)), 4) or None
    if kind == "wind_gust":
        spec["direction_deg"] = round(float(rng.uniform(0.0, 360.0)), 1)
    return {k: v for k, v in spec.items() if v is not None}


def with_drawn_fault(cfg: MissionFile, index: int, kinds: list[str], seed: int) -> MissionFile:
    """``cfg`` with run ``index``'s fault (the world's draws are left as they were)."""
    block, pos = divmod(index, len(kinds))
    order = np.random.RandomState([seed, block, 0x16]).permutation(len(kinds))
    kind = kinds[int(order[pos])]
    spec = draw_fault(kind, np.random.RandomState([seed, index, 0x17]))
    return MissionFile.model_validate({**cfg.model_dump(), "faults": {"inject": [spec]}})


def noticed(recs: list[dict[str, Any]], kind: str, t_inj_ns: int) -> bool:
    """The mission's log shows, at or after ``t_inj_ns``, that it noticed a ``kind`` fault (a
    ``fault_detected`` record, a vehicle event, a state change's reason...); True for kinds
    with nothing to notice (a gust within bounds)."""
    needles = OUTCOMES[kind].detected_by
    after = [json.dumps(r) for r in recs if r["t_ns"] >= t_inj_ns
             and r["kind"] in ("fault_detected", "state", "event", "estimate", "end")]
    return not needles or any(n in line for line in after for n in needles)


GRASPED_ELSEWHERE = "another object was grasped"
"""The end of :func:`grasped_elsewhere`'s reason (a run's ``fault_failure``)."""


def grasped_elsewhere(horizontal_error_m: float | None, target: TargetConfig) -> str:
    """Why a GRASP_READY was not on the target: the true tool point lies beyond half the
    target's larger side from its centre (another object was grasped); "" when on it or
    unknown. Precision within the target is the evaluator's (``success``), not this."""
    half_m = max(target.length_m, target.width_m) / 2.0
    if horizontal_error_m is None or horizontal_error_m <= half_m:
        return ""
    return (f"GRASP_READY {horizontal_error_m:.2f} m from the true target, beyond its half "
            f"size {half_m:.2f} m: {GRASPED_ELSEWHERE}")



def judge(out: Any) -> dict[str, Any]:
    """The fault fields of one flown run (an ``ApproachOutcome`` with its log records kept)."""
    cfg: MissionFile = out.config
    faults = faults_of(cfg)
    assert faults is not None and faults.inject
    kind = faults.inject[0].kind
    expected = expected_action(kind, cfg)
    recs: list[dict[str, Any]] = out.log.records
    kinds = {r["kind"] for r in recs}
    injected = [r for r in recs if r["kind"] == "fault_injected"]
    ev = out.reevaluate(expected_action=None if expected == COMPLETE else expected)
    res: dict[str, Any] = {"fault": kind, "expected": expected, "fault_spec":
                           faults.inject[0].model_dump(exclude_none=True)}
    problems: list[str] = []
    t_inj = injected[0]["t_ns"] if injected else None
    if t_inj is None:
        problems.append(f"never injected (state {faults.inject[0].at_state} not reached)")
    if expected == COMPLETE:
        ok = ev.reached_grasp_ready and ev.final_state == "DONE"
        if not ok:
            problems.append(f"expected GRASP_READY + DONE, ended in {ev.final_state}: "
                            f"{ev.reason} ({ev.action})")
        elif elsewhere := grasped_elsewhere(ev.horizontal_error_m, cfg.target):
            problems.append(elsewhere)
    else:
        ok = ev.final_state == "FAILSAFE" and ev.action == expected and ev.ended_safe
        if not ok:
            problems.append(f"expected FAILSAFE -> {expected}, ended in {ev.final_state}: "
                            f"{ev.reason} ({ev.action}); {ev.explanation}")
    if ev.violations:
        problems.append(f"{len(ev.violations)} envelope violation(s) on the truth")
    needles = OUTCOMES[kind].detected_by
    detected = None if t_inj is None else noticed(recs, kind, t_inj)
    missing = [k for k in LOG_KINDS if k not in kinds]
    complete_log = not missing and bool(detected)
    if missing:
        problems.append(f"log lacks {', '.join(missing)}")
    elif not detected and t_inj is not None:
        problems.append(f"the mission logged no sign of it ({' | '.join(needles)})")
    t_safe = None
    if t_inj is not None and ev.final_state == "FAILSAFE":
        fs = [r for r in recs if r["kind"] == "state" and r.get("new") == "FAILSAFE"]
        if fs:
            t_safe = round((fs[0]["t_ns"] - t_inj) * 1e-9, 3)
    res.update(expected_outcome=not problems, fault_failure="; ".join(problems),
               detected=detected, log_complete=complete_log, time_to_safe_s=t_safe)
    return res


def fault_table(runs: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per fault kind: runs, end states, matches, time to the safe state, violations, logs."""
    rows = []
    for kind in FAULT_KINDS:
        rs = [r for r in runs if r.get("fault") == kind]
        if not rs:
            continue
        ends: dict[str, int] = {}
        for r in rs:
            end = r.get("final_state", "crashed")
            ends[end] = ends.get(end, 0) + 1
        t = [r["time_to_safe_s"] for r in rs if r.get("time_to_safe_s") is not None]
        rows.append({
            "fault": kind, "runs": len(rs), "expected": rs[0].get("expected", "?"),
            "end_states": ends, "matches": sum(bool(r.get("expected_outcome")) for r in rs),
            "grasp_ready": sum(bool(r.get("reached_grasp_ready")) for r in rs),
            "safe_median_s": float(np.median(t)) if t else None,
            "safe_max_s": max(t) if t else None,
            "violations": sum(len(r.get("violations", [])) for r in rs),
            "log_complete": sum(bool(r.get("log_complete")) for r in rs)})
    return rows


def fault_failures(runs: list[dict[str, Any]]) -> list[str]:
    """One line per run that did not end in its expected outcome."""
    return [f"run {r['run']} ({r.get('fault', '?')}): "
            f"{r.get('fault_failure') or r.get('explanation', 'crashed')}"
            for r in runs if not r.get("expected_outcome")]


def print_fault_table(runs: list[dict[str, Any]]) -> int:
    """Print the per-fault table and the failures; returns the number of failed runs."""
    from rich.console import Console
    from rich.table import Table

    from eaglemission.commands import console

    rows = fault_table(runs)
    t = Table(title="per fault kind")
    for col in ("fault", "runs", "expected", "end states", "as expected", "time to safe "
                "state median/max (s)", "true envelope violations", "logs complete"):
        t.add_column(col)
    for r in rows:
        safe = ("-" if r["safe_median_s"] is None
                else f"{r['safe_median_s']:.2f} / {r['safe_max_s']:.2f}")
        t.add_row(r["fault"], str(r["runs"]), r["expected"],
                  ", ".join(f"{k} {v}" for k, v in sorted(r["end_states"].items())),
                  f"{r['matches']}/{r['runs']}", safe, str(r["violations"]),
                  f"{r['log_complete']}/{r['runs']}")
    c = console()
    if c.is_terminal:
        c = Console(width=max(c.width, 150))  # the table is wide
    c.print(t)
    tol = [r for r in runs if r.get("expected") == COMPLETE]
    if tol:
        done = sum(bool(r.get("reached_grasp_ready")) and r.get("final_state") == "DONE"
                   for r in tol)
        elsewhere = sum(GRASPED_ELSEWHERE in (r.get("fault_failure") or "") for r in tol)
        on = done - elsewhere
        c.print(f"tolerable faults completed (GRASP_READY + DONE): {done}/{len(tol)} "
                f"({done / len(tol):.0%}); on the target: {on}/{len(tol)} "
                f"({on / len(tol):.1%})")
    fails = fault_failures(runs)
    c.print(f"runs in their expected outcome: {len(runs) - len(fails)}/{len(runs)}")
    for line in fails:
        c.print(f"  FAILED {line}", markup=False, soft_wrap=True)
    return len(fails)
