"""PnP benchmark after the protocol of Li, Xu, Xie (TPAMI 2012): RPnP vs OpenCV in one run.

f = 800 px, 640x480, principal point at the centre; families: ordinary 3-D ([-2,2]^2 x [4,8] in
the camera frame), quasi-singular ([1,2]^2 x [4,8]), planar (object z = 0) and the mission's case
(the configured top face, 0.2-10 m, 40-80 deg between the optical axis and the face normal, its
4 corners). Gaussian pixel noise; rotation error = largest angle between corresponding columns
of R (deg), translation error = |t - t_true| / |t_true| (%); mean and median per cell; time
per solve.

Usage::

    python benchmarks/bench_pnp.py                 # full protocol (200 trials per cell)
    python benchmarks/bench_pnp.py --trials 50     # reduced
    python benchmarks/bench_pnp.py --quick         # smoke run (20 trials, fewer cells)

Targets checked at the end: noise-free exactness; n = 4 ordinary sigma = 2 px mean
rotation error below SQPnP's; with refinement n >= 10 medians within 10% of SQPnP's; speed at
n = 4 <= 4x SQPnP per solve, n = 1000 <= 20x n = 10.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from collections.abc import Callable
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import cv2  # noqa: E402
import numpy as np  # noqa: E402
from eaglemission.estimators.opencv_pnp import opencv_pnp  # noqa: E402
from eaglemission.estimators.rpnp import rpnp  # noqa: E402

# the synthetic protocol is test code (tests/estimators/pnp_synthetic.py)
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "estimators"))
from pnp_synthetic import (  # noqa: E402
    make_case,
    normalized,
    rotation_error_deg,
    translation_error_pct,
)

F_PX = 800.0
TARGET_LW = (0.40, 0.25)

Solver = Callable[[np.ndarray, np.ndarray], object]

METHODS: dict[str, Solver] = {
    "RPnP": lambda o, n: rpnp(o, n),
    "RPnP+LM": lambda o, n: rpnp(o, n, refine=True),
    "SQPnP": lambda o, n: opencv_pnp(o, n, method="sqpnp"),
    "IPPE": lambda o, n: opencv_pnp(o, n, method="ippe"),
    "ITERATIVE": lambda o, n: opencv_pnp(o, n, method="iterative"),
    "EPnP": lambda o, n: opencv_pnp(o, n, method="epnp"),
}


def applicable(method: str, family: str, n: int) -> bool:
    planar = family in ("planar", "mission")
    if method == "IPPE":
        return planar
    if method == "ITERATIVE" and not planar:
        return n >= 6
    return True


def run_cell(family: str, n: int, sigma_px: float, trials: int, seed: int,
             methods: list[str]) -> dict[str, dict[str, float]]:
    rs = np.random.RandomState(seed)
    cases = []
    for _ in range(trials):
        Xo, Xc, R, t = make_case("rectangle" if family == "mission" else family, n, rs,
                                 rect=TARGET_LW)
        uv = normalized(Xc) + rs.normal(scale=sigma_px / F_PX, size=(Xo.shape[0], 2))
        cases.append((Xo, uv, R, t))
    out: dict[str, dict[str, float]] = {}
    for m in methods:
        if not applicable(m, family, n):
            continue
        rot, tra = [], []
        fails = 0
        for Xo, uv, R, t in cases:
            est = METHODS[m](Xo, uv)
            if not est:
                fails += 1
                continue
            rot.append(rotation_error_deg(est.R, R))
            tra.append(translation_error_pct(est.t_m, t))
        rot_a, tra_a = np.array(rot), np.array(tra)
        out[m] = {
            "rot_mean": float(rot_a.mean()) if rot else float("nan"),
            "rot_median": float(np.median(rot_a)) if rot else float("nan"),
            "t_mean": float(tra_a.mean()) if tra else float("nan"),
            "t_median": float(np.median(tra_a)) if tra else float("nan"),
            "failures": fails,
        }
    return out


def noise_free(families: list[str], ns: list[int], trials: int, seed: int) -> dict[str, dict[str, float]]:
    rs = np.random.RandomState(seed)
    res = {}
    for fam in families:
        worst_R = worst_t = 0.0
        fails = 0
        count = 0
        for n in (ns if fam != "mission" else [4]):
            for _ in range(trials):
                Xo, Xc, R, t = make_case("rectangle" if fam == "mission" else fam, n, rs, rect=TARGET_LW)
                est = rpnp(Xo, normalized(Xc))
                count += 1
                if not est:
                    fails += 1
                    continue
                worst_R = max(worst_R, float(np.linalg.norm(est.R - R)))
                worst_t = max(worst_t, float(np.linalg.norm(est.t_m - t) / np.linalg.norm(t)))
        res[fam] = {"max_R_frobenius": worst_R, "max_t_rel": worst_t, "failures": fails, "solves": count}
    return res


def time_per_solve(method: str, family: str, n: int, reps: int, seed: int) -> float:
    rs = np.random.RandomState(seed)
    cases = []
    for _ in range(reps):
        Xo, Xc, _, _ = make_case(family, n, rs)
        cases.append((Xo, normalized(Xc) + rs.normal(scale=2 / F_PX, size=(n, 2))))
    fn = METHODS[method]
    for Xo, uv in cases[: min(10, reps)]:  # warm-up
        fn(Xo, uv)
    best = float("inf")
    for _ in range(3):  # best of 3 passes: the machine is shared
        t0 = time.perf_counter()
        for Xo, uv in cases:
            fn(Xo, uv)
        best = min(best, (time.perf_counter() - t0) / reps)
    return best


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--trials", type=int, default=200, help="trials per cell (paper: 500)")
    ap.add_argument("--quick", action="store_true", help="20 trials, sigma {0.5, 2, 5}, n {4, 10, 50}")
    ap.add_argument("--seed", type=int, default=2012)
    ap.add_argument("--json", type=str, default="", help="also write the figures to this file")
    args = ap.parse_args(argv)
    cv2.setNumThreads(1)
    trials = 20 if args.quick else args.trials
    sigmas = [0.5, 2.0, 5.0] if args.quick else [0.5, 1.0, 2.0, 3.0, 4.0, 5.0]
    ns = [4, 10, 50] if args.quick else [4, 6, 10, 50, 1000]
    families = ["ordinary", "quasi_singular", "planar", "mission"]
    methods = list(METHODS)
    report: dict[str, object] = {"trials": trials, "sigmas_px": sigmas, "ns": ns, "f_px": F_PX}

    print(f"# bench_pnp: f={F_PX:g} px, 640x480, trials/cell={trials}, seed={args.seed}")
    print(f"# opencv {cv2.__version__}, numpy {np.__version__}")

    # 1. Noise-free exactness (n = 4..50).
    nf = noise_free(families, [4, 5, 6, 10, 20, 50], max(trials // 2, 20), args.seed)
    report["noise_free"] = nf
    print("\n## noise-free RPnP (n = 4, 5, 6, 10, 20, 50; mission: the 4 corners)")
    for fam, r in nf.items():
        print(f"{fam:15s} max|R-R_true|_F={r['max_R_frobenius']:.2e}  max rel t err={r['max_t_rel']:.2e}"
              f"  failures={r['failures']}/{r['solves']}")

    # 2. Accuracy cells.
    cells: list[dict[str, object]] = []
    print("\n## accuracy: rotation error deg (mean/median), translation error % (mean/median);"
          " !k = k failures (excluded)")
    hdr = "family          n     sigma  " + "  ".join(f"{m:>24s}" for m in methods)
    print(hdr)
    for fam in families:
        for n in (ns if fam != "mission" else [4]):
            for s in sigmas:
                cell = run_cell(fam, n, s, trials, args.seed + 7 * n + int(10 * s), methods)
                cells.append({"family": fam, "n": n, "sigma_px": s, "results": cell})
                row = f"{fam:15s} {n:<5d} {s:<5.1f}  "
                parts = []
                for m in methods:
                    if m in cell:
                        c = cell[m]
                        f = f"!{c['failures']}" if c["failures"] else ""
                        tm = f"{c['t_mean']:5.2f}" if c["t_mean"] < 1e4 else " >1e4"
                        parts.append(f"{c['rot_mean']:5.2f}/{c['rot_median']:5.2f} {tm}/{c['t_median']:5.2f}{f}".rjust(24))
                    else:
                        parts.append("-".rjust(24))
                print(row + "  ".join(parts), flush=True)
    report["cells"] = cells

    # 3. Timing.
    print("\n## time per solve (us), ordinary family, sigma 2 px, best of 3 passes")
    timing: dict[str, dict[int, float]] = {}
    for m in ["RPnP", "RPnP+LM", "SQPnP", "EPnP", "ITERATIVE"]:
        timing[m] = {}
        for n in [4, 10, 100, 1000]:
            if not applicable(m, "ordinary", n):
                continue
            reps = 400 if n <= 10 else (100 if n <= 100 else 30)
            timing[m][n] = time_per_solve(m, "ordinary", n, reps, args.seed) * 1e6
        print(f"{m:10s} " + "  ".join(f"n={n}: {v:8.1f}" for n, v in timing[m].items()))
    report["time_us"] = timing

    # 4. Targets.
    print("\n## targets")
    if trials < 100:
        print(f"(only {trials} trials per cell: the accuracy comparisons below are noisy; the "
              "issue's figures use --trials 200)")
    ok_nf = all(r["max_R_frobenius"] < 1e-9 and r["max_t_rel"] < 1e-9 and r["failures"] == 0
                for r in nf.values())
    print(f"noise-free |R-R_true|_F < 1e-9 and rel t < 1e-9, no failures: {'MET' if ok_nf else 'NOT MET'}")

    def find(fam: str, n: int, s: float) -> dict[str, dict[str, float]] | None:
        for c in cells:
            if c["family"] == fam and c["n"] == n and c["sigma_px"] == s:
                return c["results"]  # type: ignore[return-value]
        return None

    c = find("ordinary", 4, 2.0)
    if c:
        a, b = c["RPnP"]["rot_mean"], c["SQPnP"]["rot_mean"]
        print(f"n=4 ordinary sigma=2: RPnP mean rot {a:.2f} deg vs SQPnP {b:.2f}: "
              f"{'MET' if a < b else 'NOT MET'}")
    worst = 0.0
    worst_cell = ""
    for cc in cells:
        if cc["n"] < 10 or cc["family"] == "mission":  # type: ignore[operator]
            continue
        r = cc["results"]
        for key in ("rot_median", "t_median"):
            ratio = r["RPnP+LM"][key] / r["SQPnP"][key]  # type: ignore[index]
            if ratio > worst:
                worst = ratio
                worst_cell = f"{cc['family']} n={cc['n']} sigma={cc['sigma_px']} {key}"
    print(f"refined n>=10 medians vs SQPnP: worst ratio {worst:.3f} ({worst_cell}): "
          f"{'MET' if worst <= 1.10 else 'NOT MET'} (target <= 1.10)")
    r4 = timing["RPnP"][4] / timing["SQPnP"][4]
    print(f"speed n=4: RPnP {timing['RPnP'][4]:.1f} us vs SQPnP {timing['SQPnP'][4]:.1f} us = {r4:.2f}x: "
          f"{'MET' if r4 <= 4 else 'NOT MET'} (target <= 4x)")
    lin = timing["RPnP"][1000] / timing["RPnP"][10]
    print(f"linearity: RPnP n=1000 / n=10 = {lin:.2f}x: {'MET' if lin <= 20 else 'NOT MET'} (target <= 20x)")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(report, fh, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
