"""Long S1/S2-like clips for soak and crash tests on scenes of the independent generator's kind.

The background is the per-pixel median of the 40 sample frames of ``../shared/data/independent``
(S1 or S2), with fresh sensor noise every frame (variance = read² + shot · signal, from the
sample's meta.json) and point targets (pixel-integrated Gaussian PSF) on piecewise-linear
keyframed trajectories (sharp turns, stops, crossings, late appearances, exits across the
border). Writes ``OUT/frames/frame_%06d.png`` (16-bit), ``OUT/truth.csv`` and ``OUT/info.json``.

    python benchmarks/long_scenes.py S1L --out /tmp/S1L --frames 3000
    /usr/bin/time -v wfviz track /tmp/S1L --tracks /tmp/S1L.csv --truth /tmp/S1L/truth.csv

NAME: S1L or S2L (first two letters pick the sample). ``--circle R`` darkens everything outside
radius R around the scene's circle centre (targets then leave the imaging circle).
"""
from __future__ import annotations

import argparse
import glob
import json
import math
from pathlib import Path

import cv2
import numpy as np
from scipy.special import erf

SRC = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "independent"
W, H = 640, 512

# target_id -> (snr, [(frame, x, y), ...]) ; exists from first to last keyframe, linear between
TRAJ = {
    "S1": {
        # one manoeuvring target: 3 sharp turns, speed changes, 100-frame stop, exit right border
        # into the vignetted bottom-right corner, then (3000-frame clips) a 2nd target enters from top
        1: (7.2, [(0, 175.17, 304.52), (150, 355, 304.5), (350, 395, 104), (500, 155, 164),
                  (800, 95, 314), (900, 95, 314), (1300, 495, 464), (1450, 660, 530)]),
        2: (7.0, [(1800, 400, -10), (2400, 250, 400), (2600, 250, 400), (3000, 600, 450)]),
    },
    "S2": {
        # T1 and T2 cross at (300,300) at frame 500 at ~60 deg; T1 stops 800-900 then exits bottom
        1: (8.0, [(0, 80.94, 124.50), (200, 361, 196), (500, 300, 300), (800, 239, 404),
                  (900, 239, 404), (1000, 239, 530)]),
        # T2: turns, crosses T1, sharp turns, runs into the dark top-left corner and exits top
        2: (6.5, [(0, 568.47, 422.86), (150, 331, 348), (300, 150, 250), (500, 300, 300),
                  (700, 450, 350), (900, 500, 100), (1200, 100, 30), (1250, 60, -20)]),
        # T3 appears at 300; T4 appears at 600 and overtakes T3 at a shallow angle at frame 1000
        3: (7.0, [(300, 520, 120), (700, 320, 220), (1500, 560, 460), (2000, 150, 400),
                  (2500, 300, 100), (2600, 300, 100), (3000, 600, 250)]),
        4: (7.0, [(600, 60, 60), (1000, 410, 310), (1300, 600, 400), (1500, 620, 100),
                  (1600, 700, 80)]),
        5: (7.5, [(2000, 50, 250), (3000, 500, 150)]),
    },
}


def position(kf, f):
    if f < kf[0][0] or f > kf[-1][0]:
        return None
    for (f0, x0, y0), (f1, x1, y1) in zip(kf, kf[1:]):
        if f0 <= f <= f1:
            t = (f - f0) / (f1 - f0)
            return x0 + t * (x1 - x0), y0 + t * (y1 - y0)
    return kf[-1][1], kf[-1][2]


def psf_patch(x, y, sigma, r=4):
    """Pixel-integrated unit-flux Gaussian on the pixels around (x, y): (ix0, iy0, patch)."""
    ix0, iy0 = int(math.floor(x)) - r, int(math.floor(y)) - r
    xs = np.arange(ix0, ix0 + 2 * r + 2)
    ys = np.arange(iy0, iy0 + 2 * r + 2)
    s = sigma * math.sqrt(2)
    px = 0.5 * (erf((xs + 0.5 - x) / s) - erf((xs - 0.5 - x) / s))
    py = 0.5 * (erf((ys + 0.5 - y) / s) - erf((ys - 0.5 - y) / s))
    return ix0, iy0, np.outer(py, px)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("name")
    ap.add_argument("--frames", type=int, default=3000)
    ap.add_argument("--circle", type=float, default=None)
    ap.add_argument("--out", required=True, help="output folder")
    ap.add_argument("--seed", type=int, default=1)
    a = ap.parse_args()
    scene = a.name[:2]
    out = Path(a.out)
    (out / "frames").mkdir(parents=True, exist_ok=True)
    meta = json.loads((SRC / scene / "meta.json").read_text())
    read, shot = meta["sensor"]["read_sigma_dn"], meta["sensor"]["shot_var_per_dn"]
    cx, cy = meta["circle_center"]
    radius = meta["circle_radius"] if a.circle is None else a.circle
    fs = sorted(glob.glob(str(SRC / scene / "frames" / "*.png")))
    bg = np.median(np.stack([cv2.imread(f, cv2.IMREAD_UNCHANGED) for f in fs]).astype(np.float32), axis=0)
    yy, xx = np.mgrid[0:H, 0:W]
    inside = np.hypot(xx - cx, yy - cy) <= radius
    if a.circle is not None:
        bg = np.where(inside, bg, np.float32(20.0))  # dark outside the (smaller) circle
    rng = np.random.default_rng(a.seed)
    sig0 = meta["psf"]["sigma0_px"]
    rows = []
    for f in range(a.frames):
        img = bg.copy()
        for tid, (snr, kf) in TRAJ[scene].items():
            p = position(kf, f)
            if p is None:
                continue
            x, y = p
            in_img = -0.5 <= x <= W - 0.5 and -0.5 <= y <= H - 0.5
            in_circ = math.hypot(x - cx, y - cy) <= radius
            vis = int(in_img and in_circ)
            if -5 <= x <= W + 4 and -5 <= y <= H + 4:
                rr = math.hypot(x - cx, y - cy) / meta["circle_radius"]
                sigma = sig0 * (1 + 0.2 * rr * rr)
                ix0, iy0, patch = psf_patch(x, y, sigma)
                xi, yi = int(round(min(max(x, 0), W - 1))), int(round(min(max(y, 0), H - 1)))
                noise = math.sqrt(read**2 + shot * float(bg[yi, xi]))
                peak_unit = psf_patch(0.0, 0.0, sigma)[2].max()  # peak pixel of a pixel-centred PSF
                flux = snr * noise / peak_unit
                ph, pw = patch.shape
                x0, y0 = max(ix0, 0), max(iy0, 0)
                x1, y1 = min(ix0 + pw, W), min(iy0 + ph, H)
                if x1 > x0 and y1 > y0:
                    sub = flux * patch[y0 - iy0:y1 - iy0, x0 - ix0:x1 - ix0]
                    sub = sub * inside[y0:y1, x0:x1]  # nothing is imaged outside the circle
                    img[y0:y1, x0:x1] += sub.astype(np.float32)
                rows.append(f"{f},{tid},{x:.4f},{y:.4f},{vis}")
            elif f < kf[-1][0]:
                rows.append(f"{f},{tid},{x:.4f},{y:.4f},0")
        var = read**2 + shot * np.maximum(img, 0)
        img = img + rng.standard_normal(img.shape, dtype=np.float32) * np.sqrt(var).astype(np.float32)
        if a.circle is not None:
            img = np.where(inside, img, 20 + rng.standard_normal(img.shape, dtype=np.float32) * read)
        img16 = np.clip(np.rint(img), 0, 16383).astype(np.uint16)
        cv2.imwrite(str(out / "frames" / f"frame_{f:06d}.png"), img16, [cv2.IMWRITE_PNG_COMPRESSION, 1])
        if f % 500 == 0:
            print(f"{a.name}: frame {f}", flush=True)
    (out / "truth.csv").write_text("frame,target_id,x,y,visible\n" + "\n".join(rows) + "\n")
    (out / "info.json").write_text(json.dumps({"scene": scene, "frames": a.frames, "circle_radius": radius,
                                               "circle_center": [cx, cy], "targets": {
                                                   str(k): {"snr": v[0], "keyframes": v[1]}
                                                   for k, v in TRAJ[scene].items()}}, indent=1))
    print("done", out)


if __name__ == "__main__":
    main()
