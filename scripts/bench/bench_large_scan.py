#!/usr/bin/env python3
"""Benchmark (not a CI test): a thin-slice head-and-neck CT of 512 x 512 x 800 voxels, synthetic.

The phantom head (``make_phantom``) is sampled on a 0.8 x 0.8 x 0.625 mm grid, 410 mm across and 500 mm tall, and
shoulders are added below the neck (a soft-tissue trunk 380 mm wide whose top rises from the
neck to the shoulder line), as in a head-and-neck scan. It measures, per step, the wall time and the peak resident
memory
(RSS sampled every 20 ms, minus what the process held before the step), checks that the head
mask stops at the neck (the shoulders do not join it) and prints a Markdown section for
docs/benchmarks.md (its own section ``large-scan``, kept by bench.py when it rewrites the file; pasted by hand).

    python3 scripts/bench/bench_large_scan.py                       # 800 x 512 x 512 (about 5 GB, minutes)
    python3 scripts/bench/bench_large_scan.py --shape 200 256 256   # a quick look
    python3 scripts/bench/bench_large_scan.py --downsample 2        # the volume block-averaged 2x per axis first
"""
from __future__ import annotations

import argparse
import json
import sys
import threading
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from pdehead_addon import CTVolume, make_phantom, segment_head  # noqa: E402
from pdehead_addon.core.ct_volume import downsample_volume  # noqa: E402

#: The shoulders: trunk half-width / half-depth (mm), the z of the shoulder line at the neck
#: and at the trunk's sides (mm, patient z; the phantom's chin is at -91).
SHOULDER = dict(half_width=190.0, half_depth=105.0, centre_y=25.0, z_neck=-150.0, z_side=-190.0)
#: Field of view (z, y, x) mm of the synthetic scan: 500 mm tall, 410 mm across (0.8 mm pixels at 512).
FOV_MM = (500.0, 409.6, 409.6)


class PeakRSS:
    """Peak resident memory (bytes) of this process while the ``with`` block runs, by sampling."""

    def __init__(self, interval: float = 0.02):
        import psutil
        self.proc = psutil.Process()
        self.interval = interval

    def __enter__(self):
        self.base = self.peak = self.proc.memory_info().rss
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()
        return self

    def _run(self):
        while not self._stop.is_set():
            self.peak = max(self.peak, self.proc.memory_info().rss)
            time.sleep(self.interval)

    def __exit__(self, *exc):
        self._stop.set()
        self._thread.join()
        self.peak = max(self.peak, self.proc.memory_info().rss)
        return False


def add_shoulders(ct: CTVolume, hu: float = 40.0) -> np.ndarray:
    """Paint the trunk and shoulders into ``ct.data`` in place; returns their mask per slice (z only).

    The top of the trunk is the shoulder line: at the neck (|x| <= 60 mm) it is ``z_neck``,
    falling to ``z_side`` at the trunk's sides, so the upper shoulder slices show the shoulders
    as two blobs beside the neck and the lower ones one body.
    """
    s = SHOULDER
    nz, ny, nx = ct.shape
    dz, dy, dx = ct.spacing
    xs = ct.origin[0] + dx * np.arange(nx)
    ys = ct.origin[1] + dy * np.arange(ny)
    zs = ct.origin[2] + dz * np.arange(nz)
    ellipse = ((xs[None, :] / s["half_width"]) ** 2 + ((ys[:, None] - s["centre_y"]) / s["half_depth"]) ** 2) <= 1
    # shoulder-line height at each x: z_neck inside |x| <= 60, then sloping down to z_side at the side
    t = np.clip((np.abs(xs) - 60.0) / (s["half_width"] - 60.0), 0.0, 1.0)
    top = s["z_neck"] + (s["z_side"] - s["z_neck"]) * t ** 2
    rng = np.random.default_rng(5)
    trunk_slices = np.zeros(nz, bool)
    for k in np.flatnonzero(zs <= s["z_neck"]):
        inside = ellipse & (zs[k] <= top)[None, :]
        if inside.any():
            trunk_slices[k] = True
            ct.data[k][inside] = hu + 20.0 * rng.standard_normal(int(inside.sum()), dtype=np.float32)
    return trunk_slices


def run(shape, downsample: int, out_json: Path | None) -> dict:
    nz, ny, nx = shape
    spacing = tuple(f / n for f, n in zip(FOV_MM, shape))       # 0.625 x 0.8 x 0.8 mm for 800 x 512 x 512
    result: dict = {"shape": [nz, ny, nx], "spacing_mm": spacing, "downsample": downsample}
    with PeakRSS() as m:
        t = time.perf_counter()
        ph = make_phantom(shape=shape, spacing=spacing)
        ct = ph.ct
        truth = ph.head_mask
        del ph
        trunk = add_shoulders(ct)
        result["make_s"] = time.perf_counter() - t
    result["make_peak_gb"] = (m.peak - m.base) / 1e9
    result["process_peak_gb"] = m.peak / 1e9
    result["volume_gb"] = ct.data.nbytes / 1e9
    if downsample > 1:
        with PeakRSS() as m:
            t = time.perf_counter()
            ct = downsample_volume(ct, downsample)
            result["downsample_s"] = time.perf_counter() - t
        result["downsample_peak_gb"] = (m.peak - m.base) / 1e9
        result["process_peak_gb"] = max(result["process_peak_gb"], m.peak / 1e9)
        # the truth on the coarse grid: more than half of each block inside the head
        truth = downsample_volume(CTVolume(truth.astype(np.float32), (1.0, 1.0, 1.0)), downsample).data > 0.5
        trunk = trunk[: ct.shape[0] * downsample].reshape(-1, downsample).any(axis=1)
    with PeakRSS() as m:
        t = time.perf_counter()
        seg = segment_head(ct)
        result["segment_s"] = time.perf_counter() - t
    result["segment_peak_gb"] = (m.peak - m.base) / 1e9
    result["process_peak_gb"] = max(result["process_peak_gb"], m.peak / 1e9)
    mask = seg.mask
    dz, dy, dx = ct.spacing
    zs = ct.origin[2] + dz * np.arange(ct.shape[0])
    width = np.array([(np.ptp(np.flatnonzero(m.any(axis=0))) + 1) * dx if m.any() else 0.0 for m in mask])
    result["mask_lowest_z_mm"] = float(zs[np.flatnonzero(mask.any(axis=(1, 2)))[0]]) if mask.any() else None
    result["mask_max_width_mm"] = float(width.max())
    result["mask_voxels_in_trunk_slices"] = int(mask[trunk].sum())
    result["shoulder_top_z_mm"] = SHOULDER["z_neck"]
    above = ~trunk
    from pdehead_addon.validation import metrics as M
    per = M.slice_jaccard_on_head(mask[above], truth[above], 0.01)
    result["jaccard_above_shoulders_mean"] = float(per.mean())
    result["jaccard_above_shoulders_min"] = float(per.min())
    result["segmentation_meta"] = {k: seg.meta["cleanup"].get(k) for k in ("neck_cut", "head_voxels")}
    result["warnings"] = seg.meta.get("warnings", [])
    if out_json:
        out_json.write_text(json.dumps(result, indent=2, default=str))
    return result


def markdown(r: dict) -> str:
    nz, ny, nx = r["shape"]
    lines = [f"### {nx} x {ny} x {nz} voxels ({r['volume_gb']:.2f} GB float32), downsample {r['downsample']}",
             "",
             "| step | wall s | peak RSS above the step's start (GB) |",
             "|---|---:|---:|",
             f"| synthetic scan (phantom + shoulders) | {r['make_s']:.1f} | {r['make_peak_gb']:.2f} |"]
    if r["downsample"] > 1:
        lines.append(f"| block-mean downsample | {r['downsample_s']:.1f} | {r['downsample_peak_gb']:.2f} |")
    lines += [f"| segment_head | {r['segment_s']:.1f} | {r['segment_peak_gb']:.2f} |",
              "",
              f"Process peak RSS (all steps): {r['process_peak_gb']:.2f} GB. Head mask: lowest slice at z = "
              f"{r['mask_lowest_z_mm']:.1f} mm (shoulder line at the neck: {r['shoulder_top_z_mm']:.0f} mm), "
              f"widest slice {r['mask_max_width_mm']:.0f} mm, {r['mask_voxels_in_trunk_slices']} mask voxels in "
              f"slices with shoulders; per-slice Jaccard above the shoulders mean "
              f"{r['jaccard_above_shoulders_mean']:.4f}, min {r['jaccard_above_shoulders_min']:.4f}."]
    return "\n".join(lines)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--shape", type=int, nargs=3, default=(800, 512, 512), metavar=("NZ", "NY", "NX"))
    p.add_argument("--downsample", type=int, default=1)
    p.add_argument("--json", type=Path)
    args = p.parse_args(argv)
    r = run(tuple(args.shape), args.downsample, args.json)
    print(json.dumps(r, indent=2, default=str))
    print()
    print(markdown(r))
    return 0


if __name__ == "__main__":
    sys.exit(main())
