#!/usr/bin/env python3
"""Benchmark of the head segmentation (paper eq. 16-21 + clean-up) against scikit-image's Chan-Vese.

What it measures, in one run on this machine:

* ``segment_head`` on the whole CThead (113 x 256 x 256): median (and all) wall times of
  ``--repeats`` runs, its per-slice Jaccard against the independent threshold reference
  (:func:`pdehead_addon.validation.metrics.reference_head_mask` with ``REFERENCE_SETTINGS``);
* the peer: ``skimage.segmentation.chan_vese`` run once on every one of the same head slices,
  given a fair set-up (the same windowed [0, 1] image, its default length weight mu=0.25,
  lambda1 = lambda2 = 1, tol 1e-3, ``--peer-iterations`` at most (default 200: its energy has
  levelled off by then; skimage's own default is 500), the brighter phase taken as the head);
  its per-slice Jaccard raw and after the same clean-up as ours (``clean_head_mask``), and the
  ratio of the peer's total time to our median;
* peak memory (RSS) of ``segment_head`` on a synthetic 300 x 512 x 512 head volume, in a
  separate process (peak RSS over the call, sampled every 10 ms, and the process's lifetime
  peak ``ru_maxrss``; the input volume itself is 0.31 GB of it).

Usage::

    python3 scripts/bench/bench_segmentation.py [--repeats 5] [--json out.json] [--skip-peer] [--skip-memory]

The measurements are importable (``measure_segmentation``, ``measure_peer``,
``measure_memory``, ``reference_for``) for scripts/bench/bench.py.
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import statistics
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any, Sequence

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "scripts"))

from _common import CTHEAD_RAW16_OPTIONS, CTHEAD_TIFF8_OPTIONS, SHARED_DATA as DATA, timed  # noqa: E402
from pdehead_addon import CTVolume, load_ct, segment_head  # noqa: E402
from pdehead_addon.segment import segmentation as S  # noqa: E402
from pdehead_addon.validation import metrics as M  # noqa: E402

#: Where each real data set is and how it is loaded (scripts/_common.py owns the options).
LOAD_OPTIONS = {
    "cthead": (("cthead_stanford", "raw16"), CTHEAD_RAW16_OPTIONS),
    "cthead_tiff8": (("cthead_stanford", "tiff8"), CTHEAD_TIFF8_OPTIONS),
    "ge": (("ct_head_ge_tilt_dicom", "dicom"), {}),
}


def load_dataset(key: str) -> CTVolume:
    """One of the real data sets of ../shared/data (keys of ``LOAD_OPTIONS``)."""
    parts, options = LOAD_OPTIONS[key]
    return load_ct(DATA.joinpath(*parts), **options)


def reference_for(key: str, ct: CTVolume) -> tuple[np.ndarray | None, str]:
    """The independent reference mask of a real data set and a description of how it was made."""
    settings = M.REFERENCE_SETTINGS.get(key)
    if settings is None:
        return None, "no reference for this data set"
    text = ", ".join(f"{k}={v:g}" for k, v in settings.items())
    return M.reference_head_mask(ct, **settings), f"pdehead_addon.validation.metrics.reference_head_mask({text})"


def measure_segmentation(ct: CTVolume, repeats: int = 5, reference: np.ndarray | None = None,
                         **params) -> dict[str, Any]:
    """Median wall time of ``segment_head(ct, **params)`` over ``repeats`` runs, and its accuracy."""
    stats, seg = timed(lambda: segment_head(ct, **params), repeats)
    times = stats["runs_s"]
    out: dict[str, Any] = {
        "name": "pdehead_addon.segment_head (3-D Chan-Vese soft model eq. 16-21, coarse-to-fine, + clean-up)",
        "shape": list(ct.shape), "spacing_mm": list(ct.spacing), "repeats": len(times),
        "runs_s": times, "median_s": statistics.median(times), "min_s": min(times),
        "iterations_full_grid": int(seg.iterations), "solver": seg.meta.get("solver"),
        "cleanup": seg.meta.get("cleanup"), "c1": seg.c1, "c2": seg.c2, "window": seg.meta.get("window"),
    }
    if reference is not None:
        per = M.slice_jaccard_on_head(seg.mask, reference)
        out.update(jaccard=M.jaccard(seg.mask, reference), slice_jaccard_mean=float(per.mean()),
                   slice_jaccard_min=float(per.min()),
                   slice_jaccard_min_at=int(M.head_slices(reference)[int(np.argmin(per))]),
                   head_slices=int(len(per)))
    out["_segmentation"] = seg
    return out


def measure_peer(ct: CTVolume, reference: np.ndarray, window: Sequence[float] | None = None,
                 slices: Sequence[int] | None = None, max_num_iter: int = 200, mu: float = 0.25) -> dict[str, Any]:
    """skimage.segmentation.chan_vese once on each head slice (fair set-up, see module doc)."""
    from skimage.segmentation import chan_vese
    window = S.auto_window(ct.data) if window is None else tuple(window)
    img = S.window_intensities(ct.data, window).astype(np.float64)
    slices = M.head_slices(reference) if slices is None else np.asarray(slices)
    raw = np.zeros(ct.shape, dtype=bool)
    slice_times, iters = [], []
    for k in slices:
        t0 = time.perf_counter()
        seg, _, energies = chan_vese(img[k], mu=mu, lambda1=1.0, lambda2=1.0, tol=1e-3, max_num_iter=max_num_iter,
                                     dt=0.5, init_level_set="checkerboard", extended_output=True)
        slice_times.append(time.perf_counter() - t0)
        iters.append(len(energies))
        inside = img[k][seg].mean() if seg.any() else -1.0
        outside = img[k][~seg].mean() if (~seg).any() else -1.0
        raw[k] = seg if inside >= outside else ~seg
    t0 = time.perf_counter()
    cleaned, _ = S.clean_head_mask(raw, ct.data, window, ct.spacing)
    cleanup_s = time.perf_counter() - t0

    def per_slice(mask):
        inter = np.count_nonzero(mask[slices] & reference[slices], axis=(1, 2))
        union = np.count_nonzero(mask[slices] | reference[slices], axis=(1, 2))
        return inter / np.maximum(union, 1)

    j_raw, j_clean = per_slice(raw), per_slice(cleaned)
    return {
        "name": f"skimage.segmentation.chan_vese per slice (mu={mu}, lambda1=lambda2=1, tol=1e-3, "
                f"max_num_iter={max_num_iter}, dt=0.5, checkerboard init; brighter phase = head)",
        "slices": int(len(slices)), "total_s": float(sum(slice_times)),
        "per_slice_median_s": statistics.median(slice_times), "iterations_median": statistics.median(iters),
        "clean_up_s": cleanup_s,
        "slice_jaccard_mean_raw": float(j_raw.mean()), "slice_jaccard_min_raw": float(j_raw.min()),
        "slice_jaccard_mean_cleaned": float(j_clean.mean()), "slice_jaccard_min_cleaned": float(j_clean.min()),
    }


# ------------------------------------------------------------------------------------------------ memory
def synthetic_head(shape: Sequence[int] = (300, 512, 512), spacing: Sequence[float] = (0.8, 0.5, 0.5),
                   noise: float = 20.0, seed: int = 0) -> CTVolume:
    """A large synthetic head CT (HU): ellipsoidal skin, 7 mm skull, brain, a pillow and a table.

    Built slab by slab into one float32 array, so its own peak memory is the volume plus a few slices.
    """
    nz, ny, nx = shape
    dz, dy, dx = spacing
    data = np.empty(shape, dtype=np.float32)
    rng = np.random.default_rng(seed)
    y = (np.arange(ny) - ny / 2) * dy
    x = (np.arange(nx) - nx / 2) * dx
    yy, xx = np.meshgrid(y, x, indexing="ij")
    for k0 in range(0, nz, 16):
        k1 = min(nz, k0 + 16)
        z = ((np.arange(k0, k1) - nz * 0.55) * dz)[:, None, None]
        r = np.sqrt((xx / 75.0) ** 2 + (yy / 95.0) ** 2 + (z / 110.0) ** 2)
        slab = np.full(r.shape, -1000.0, np.float32)
        slab[r < 1.0] = 40.0
        slab[(r < 0.95) & (r > 0.88)] = 1000.0
        slab[r <= 0.88] = 32.0
        slab[(yy[None] > 95.0 * np.sqrt(np.clip(1 - (xx / 75.0) ** 2 - (z / 110.0) ** 2, 0, 1))) & (yy[None] < 112)
             & (np.abs(xx[None]) < 70) & (r >= 1.0)] = -300.0   # a pillow under the back of the head
        slab[:, (yy > 118) & (yy < 121)] = 100.0                # a table top
        slab += rng.normal(0.0, noise, slab.shape).astype(np.float32)
        data[k0:k1] = slab
    return CTVolume(data, spacing, meta={"source": "synthetic head for the memory benchmark", "units": "HU"})


def _memory_child(shape, spacing) -> dict[str, Any]:
    import psutil
    proc = psutil.Process()
    ct = synthetic_head(shape, spacing)
    baseline = proc.memory_info().rss
    peak = [baseline]
    stop = threading.Event()

    def sample():
        while not stop.is_set():
            peak[0] = max(peak[0], proc.memory_info().rss)
            time.sleep(0.01)

    sampler = threading.Thread(target=sample, daemon=True)
    sampler.start()
    t0 = time.perf_counter()
    seg = segment_head(ct)
    seconds = time.perf_counter() - t0
    stop.set()
    sampler.join()
    peak[0] = max(peak[0], proc.memory_info().rss)
    maxrss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024  # kB on Linux
    gb = 1024.0 ** 3
    return {"shape": list(shape), "spacing_mm": list(spacing), "input_gb": ct.data.nbytes / gb,
            "rss_before_gb": baseline / gb, "peak_rss_during_gb": peak[0] / gb,
            "peak_rss_increase_gb": (peak[0] - baseline) / gb, "ru_maxrss_gb": maxrss / gb,
            "seconds": seconds, "head_fraction": float(np.count_nonzero(seg.mask)) / seg.mask.size}


def measure_memory(shape: Sequence[int] = (300, 512, 512), spacing: Sequence[float] = (0.8, 0.5, 0.5)) -> dict:
    """Peak memory of segment_head on a synthetic volume, measured in a fresh Python process."""
    code = ("import json, sys; sys.path.insert(0, %r); import bench_segmentation as b; "
            "print(json.dumps(b._memory_child(%r, %r)))" % (str(Path(__file__).parent), tuple(shape), tuple(spacing)))
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


# ------------------------------------------------------------------------------------------------ main
def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeats", type=int, default=5, help="runs of segment_head (median reported)")
    parser.add_argument("--json", type=Path, help="also write the results as JSON here")
    parser.add_argument("--peer-iterations", type=int, default=200, help="max_num_iter of skimage's chan_vese")
    parser.add_argument("--skip-peer", action="store_true", help="do not run skimage's chan_vese")
    parser.add_argument("--skip-memory", action="store_true", help="do not run the 300x512x512 memory test")
    parser.add_argument("--memory-shape", type=int, nargs=3, default=(300, 512, 512), metavar=("NZ", "NY", "NX"))
    args = parser.parse_args(argv)

    result: dict[str, Any] = {"machine": {"cpu_count": os.cpu_count(), "platform": platform.platform(),
                                          "python": platform.python_version(), "numpy": np.__version__,
                                          "load_average": os.getloadavg()},
                              "date": time.strftime("%Y-%m-%d %H:%M:%S")}
    ct = load_dataset("cthead")
    reference, ref_text = reference_for("cthead", ct)
    ours = measure_segmentation(ct, args.repeats, reference)
    seg = ours.pop("_segmentation")
    result["cthead"] = {"reference": ref_text, "ours": ours}
    print(f"CThead {tuple(ct.shape)}: segment_head median {ours['median_s']:.3f} s over {ours['repeats']} runs "
          f"(min {ours['min_s']:.3f} s); per-slice Jaccard mean {ours['slice_jaccard_mean']:.4f}, "
          f"min {ours['slice_jaccard_min']:.4f} over {ours['head_slices']} head slices")
    if not args.skip_peer:
        peer = measure_peer(ct, reference, seg.meta["window"], max_num_iter=args.peer_iterations)
        ratio = peer["total_s"] / ours["median_s"]
        result["cthead"].update(peer=peer, ratio=ratio)
        print(f"  peer {peer['name']}: {peer['total_s']:.1f} s on {peer['slices']} slices "
              f"({peer['per_slice_median_s']:.2f} s/slice); Jaccard raw {peer['slice_jaccard_mean_raw']:.4f}/"
              f"{peer['slice_jaccard_min_raw']:.4f}, with our clean-up {peer['slice_jaccard_mean_cleaned']:.4f}/"
              f"{peer['slice_jaccard_min_cleaned']:.4f} (mean/min)")
        print(f"  ratio peer / ours = {ratio:.1f}x")
    if not args.skip_memory:
        mem = measure_memory(args.memory_shape)
        result["memory"] = mem
        print(f"memory, synthetic {tuple(mem['shape'])} float32 ({mem['input_gb']:.2f} GB input): peak RSS "
              f"{mem['peak_rss_during_gb']:.2f} GB during segment_head (+{mem['peak_rss_increase_gb']:.2f} GB over "
              f"the loaded input), lifetime ru_maxrss {mem['ru_maxrss_gb']:.2f} GB, {mem['seconds']:.1f} s")
    if args.json:
        args.json.write_text(json.dumps(result, indent=2, default=float))
        print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
