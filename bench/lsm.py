"""LSM precision and throughput, side by side with OpenCV, on the same patches.

``python -m bench.lsm [--n 2000] [--seed 0] [--workers W]``

Every method matches the same 13 × 13 templates into the same search images (41 × 41
px, exact warps from :mod:`bench.patches`, noise σ = 2 grey levels, 8-bit), starting
from the search-image centre (true shift uniform within ±1 px):

* ``LSM numba`` — :func:`core.lsm.match` (inverse compositional, 8 parameters),
  resampling the 2× cubic-spline upsampled search images (the default), with its
  compiled steps (:mod:`core.lsm_kernel`; numba);
* ``LSM numpy`` — the same call with ``SOMACAP_NO_NUMBA=1``: the numpy reference path
  (what runs inside Blender, which does not bundle numba);
* ``LSM bilinear`` — ``upsample=False`` (bilinear on the originals; numba when there);
* ``ECC affine`` — ``cv2.findTransformECC(MOTION_AFFINE)`` in a loop over patches
  (OpenCV's default criteria, 50 iterations / 1e-3, no Gaussian pre-blur, which
  only lost precision here);
* ``KLT`` — ``cv2.calcOpticalFlowPyrLK`` (13 × 13 window, one level) in a loop.

Cases: pure shift; gain 1.3 and offset +20 in the search image; affine (scales
0.9–1.1, shears ±0.1).  Columns: fraction of matches returned as valid, mean and
RMS position error of the valid ones (px), for LSM the RMS error over its own
predicted σ, and matches per second (all patches of the case, best of ``--repeat``
runs, the methods taking turns): wall clock, OpenCV with its default threads
(:func:`core.lsm.match` in the calling thread with OpenBLAS on one thread; ``--workers
W`` splits the patches over W threads, 0 = one per core), and per CPU second of the
process (all its threads; the steadier figure on a shared machine).  The load average of the machine
is printed before and after, and the seconds of the first compiled call of this
process (numba compiling, or loading its disk cache; ``--jit-cold`` also times a cold
compile and a cache load in fresh processes with an empty ``NUMBA_CACHE_DIR``).
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time

import cv2
import numpy as np

from bench.patches import PatchPairs, make_pairs
from core import lsm_kernel
from core.lsm import match

HALF = 6
ECC_CRITERIA = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 50, 1e-3)
KLT_CRITERIA = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 30, 0.01)


WORKERS = {"n": 1}  # match(workers=...), set by --workers


def run_lsm(P: PatchPairs, upsample: bool, compiled: bool = True):
    n = len(P.template)
    start = np.full((n, 2), P.centre)
    old = os.environ.get(lsm_kernel.ENV_OFF)
    os.environ[lsm_kernel.ENV_OFF] = "0" if compiled else "1"
    try:
        r = match(
            P.template,
            P.search,
            start,
            start,
            half=HALF,
            template_index=np.arange(n),
            search_index=np.arange(n),
            upsample=upsample,
            workers=WORKERS["n"],
        )
    finally:
        if old is None:
            del os.environ[lsm_kernel.ENV_OFF]
        else:
            os.environ[lsm_kernel.ENV_OFF] = old
    return r.uv, r.ok, r.sigma_uv


def run_ecc(P: PatchPairs):
    n = len(P.template)
    c = int(P.centre)
    uv = np.full((n, 2), np.nan)
    for i in range(n):
        tmpl = P.template[i, c - HALF : c + HALF + 1, c - HALF : c + HALF + 1]
        w = np.array([[1, 0, c - HALF], [0, 1, c - HALF]], np.float32)
        try:
            _, w = cv2.findTransformECC(
                tmpl, P.search[i], w, cv2.MOTION_AFFINE, ECC_CRITERIA, None, 1
            )
        except cv2.error:
            continue
        uv[i] = w[:, 2] + w[:, :2] @ np.array([HALF, HALF], np.float32)
    return uv, np.all(np.isfinite(uv), axis=1), None


def run_klt(P: PatchPairs):
    n = len(P.template)
    pt = np.array([[[P.centre, P.centre]]], np.float32)
    uv = np.full((n, 2), np.nan)
    for i in range(n):
        p, st, _ = cv2.calcOpticalFlowPyrLK(
            P.template[i],
            P.search[i],
            pt,
            None,
            winSize=(2 * HALF + 1, 2 * HALF + 1),
            maxLevel=0,
            criteria=KLT_CRITERIA,
        )
        if st[0, 0]:
            uv[i] = p[0, 0]
    return uv, np.all(np.isfinite(uv), axis=1), None


METHODS = {
    "LSM numba": lambda P: run_lsm(P, True),
    "LSM numpy": lambda P: run_lsm(P, True, compiled=False),
    "LSM bilinear": lambda P: run_lsm(P, False),
    "ECC affine": run_ecc,
    "KLT": run_klt,
}

CASES = {
    "shift": {},
    "gain 1.3 +20": {"gain": 1.3, "offset": 20.0},
    "affine": {"scale": (0.9, 1.1), "shear": 0.1},
}


def evaluate(n: int, seed: int, repeat: int = 5) -> list[dict]:
    rows = []
    for case, kw in CASES.items():
        P = make_pairs(n, seed=seed, max_shift=1.0, noise=2.0, **kw)
        dt = dict.fromkeys(METHODS, np.inf)
        dc = dict.fromkeys(METHODS, np.inf)
        out = {}
        # Best of `repeat`, the methods taking turns: on a shared machine whose load
        # drifts, every method sees the same spells of load.
        for _ in range(repeat):
            for name, fn in METHODS.items():
                t0, c0 = time.perf_counter(), time.process_time()
                out[name] = fn(P)
                dt[name] = min(dt[name], time.perf_counter() - t0)
                dc[name] = min(dc[name], time.process_time() - c0)
        for name, (uv, ok, sig) in out.items():
            err = uv - P.uv_true
            good = ok & np.all(np.isfinite(err), axis=1)
            d = np.linalg.norm(err[good], axis=1)
            rms = float(np.sqrt(np.mean(err[good] ** 2))) if good.any() else np.nan
            ratio = (rms / float(np.sqrt(np.mean(sig[good] ** 2)))) if sig is not None else np.nan
            rows.append(
                dict(
                    case=case,
                    method=name,
                    valid=float(good.mean()),
                    mean_px=float(d.mean()) if d.size else np.nan,
                    rms_px=rms,
                    ratio=ratio,
                    rate=n / dt[name],
                    cpu_rate=n / max(dc[name], 1e-9),
                )
            )
    return rows


def first_call_seconds() -> float:
    """Wall-clock seconds of this process's first compiled :func:`match` (numba compiling
    or loading its disk cache, plus a 16-patch match), NaN without numba."""
    if not lsm_kernel.enabled():
        return float("nan")
    t0 = time.perf_counter()
    run_lsm(make_pairs(16, seed=1), True)
    run_lsm(make_pairs(16, seed=1), False)
    return time.perf_counter() - t0


def jit_cold_seconds() -> tuple[float, float]:
    """First-call seconds in two fresh processes sharing an empty ``NUMBA_CACHE_DIR``:
    a cold compile, then a disk-cache load (the process start and imports not counted)."""
    code = "import bench.lsm as b; print(b.first_call_seconds())"
    out = []
    with tempfile.TemporaryDirectory() as d:
        env = dict(os.environ, NUMBA_CACHE_DIR=d)
        env.pop(lsm_kernel.ENV_OFF, None)
        for _ in range(2):
            r = subprocess.run(
                [sys.executable, "-c", code],
                env=env,
                capture_output=True,
                text=True,
                check=True,
                cwd=os.path.dirname(os.path.dirname(os.path.abspath(__file__))),
            )
            out.append(float(r.stdout.split()[-1]))
    return out[0], out[1]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=2000, help="patches per case")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--repeat", type=int, default=5, help="timing: best of this many runs")
    ap.add_argument(
        "--workers",
        type=int,
        default=1,
        help="LSM threads (core.lsm.match(workers=); 0: one per core)",
    )
    ap.add_argument(
        "--jit-cold",
        action="store_true",
        help="also time a cold numba compile and a cache load (fresh processes)",
    )
    args = ap.parse_args(argv)
    WORKERS["n"] = args.workers
    first = first_call_seconds()
    cold = jit_cold_seconds() if args.jit_cold and lsm_kernel.enabled() else None
    load0 = os.getloadavg()
    rows = evaluate(args.n, args.seed, args.repeat)
    load1 = os.getloadavg()
    print(
        f"LSM vs OpenCV: {args.n} patches per case, 13x13 templates, noise sigma 2, "
        f"OpenCV {cv2.__version__}; {os.cpu_count()} CPUs, load average (1 min) "
        f"{load0[0]:.2f} before, {load1[0]:.2f} after; LSM workers {args.workers}"
    )
    nb = lsm_kernel.numba
    print(
        f"numba {nb.__version__ if nb else 'missing'}"
        f"{'' if lsm_kernel.enabled() else ' (off: LSM numba rows run numpy)'}; first "
        f"compiled call of this process {first:.2f} s (compile or disk-cache load)"
        + (
            ""
            if cold is None
            else f"; fresh processes, empty cache: cold compile "
            f"{cold[0]:.1f} s, then cache load {cold[1]:.2f} s"
        )
    )
    print(
        f"{'case':14s} {'method':13s} {'valid':>6s} {'mean|e| px':>10s} {'rms px':>8s} "
        f"{'rms/pred':>8s} {'matches/s':>10s} {'/cpu-s':>8s}"
    )
    for r in rows:
        ratio = "" if np.isnan(r["ratio"]) else f"{r['ratio']:.2f}"
        print(
            f"{r['case']:14s} {r['method']:13s} {r['valid']:6.3f} {r['mean_px']:10.4f} "
            f"{r['rms_px']:8.4f} {ratio:>8s} {r['rate']:10.0f} {r['cpu_rate']:8.0f}"
        )
    for key, what in (("rate", "wall clock"), ("cpu_rate", "per CPU second")):
        shift = {r["method"]: r[key] for r in rows if r["case"] == "shift"}
        ecc, klt = shift["ECC affine"], shift["KLT"]
        print(
            f"throughput (shift case, {what}): "
            + "; ".join(
                f"{m} {shift[m]:.0f}/s = {shift[m] / ecc:.1f}x ECC loop, "
                f"{shift[m] / klt:.2f}x KLT loop"
                for m in ("LSM numba", "LSM numpy", "LSM bilinear")
            )
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
