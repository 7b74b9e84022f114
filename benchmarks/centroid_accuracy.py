"""Centroid accuracy study: GEWC, improved GEWC, intensity centroid, Gaussian fit vs the CRB.

For each (peak SNR, spot σ) case, ``--samples`` frames of white Gaussian noise (σ_n = 1) each
hold one pixel-integrated Gaussian spot (``wfviz.synth.psf.add_gaussian_spot``, peak = SNR) at
a random sub-pixel position. The tracker's measurement path is followed: residual (background
known, or the 5×5 top-hat of ``wfviz.stages.background``) → ``wfviz.stages.detection.detect`` (threshold
mean + 4·std of the residual, 8-connected components) → the component nearest the truth →
``wfviz.stages.centroid.measure`` with every method in the same window (the tracker's window size).
The Cramér–Rao bound of each sample (``wfviz.stages.centroid.position_crb``, unknown peak, σ and
background) is averaged over the detected samples.

Run:  python benchmarks/centroid_accuracy.py            (full study, writes the plot)
      python benchmarks/centroid_accuracy.py --samples 200 --no-plot   (quick look)
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from wfviz.config import DetectionConfig
from wfviz.stages.background import suppress_background
from wfviz.stages.centroid import measure, position_crb
from wfviz.stages.detection import detect
from wfviz.synth.psf import add_gaussian_spot

METHODS = ("gewc", "gewc-weighted", "intensity", "gaussian")
LABELS = {"gewc": "GEWC (faithful)", "gewc-weighted": "GEWC weighted (improved)",
          "intensity": "intensity centroid", "gaussian": "Gaussian fit"}
SNRS = (3.0, 5.0, 10.0, 20.0, 30.0)
SIGMAS = (0.5, 1.0, 1.5)
ROOT = Path(__file__).resolve().parents[1]


@dataclass
class CaseResult:
    """One (SNR, σ) case: detection rate, RMS radial error per method, and the bound."""

    snr: float
    sigma: float
    samples: int
    detected: int
    rms: dict[str, float] = field(default_factory=dict)
    p95: dict[str, float] = field(default_factory=dict)
    failed: dict[str, int] = field(default_factory=dict)
    crb: float = float("nan")
    threshold: float = float("nan")

    @property
    def detection_rate(self) -> float:
        return self.detected / self.samples if self.samples else float("nan")


def run_case(snr: float, sigma: float, samples: int, seed: int, background: str = "known",
             frame: int = 256, k_sigma: float = 4.0, match_radius: float = 2.0,
             methods: tuple[str, ...] = METHODS) -> CaseResult:
    """Simulate ``samples`` frames of one case and measure every method on each detection."""
    rng = np.random.default_rng([seed, round(snr * 100), round(sigma * 100)])
    det_cfg = DetectionConfig(k_sigma=k_sigma)
    region = np.ones((frame, frame), bool)
    errors: dict[str, list[float]] = {m: [] for m in methods}
    failed = dict.fromkeys(methods, 0)
    crb2: list[float] = []
    thresholds: list[float] = []
    detected = 0
    for _ in range(samples):
        x, y = frame / 2 + rng.uniform(-0.5, 0.5, size=2)
        noise = rng.normal(0.0, 1.0, (frame, frame))
        if background == "known":            # residual = frame - known background
            residual = noise
            add_gaussian_spot(residual, x, y, snr, sigma)
        else:                                # 5x5 top-hat of a flat sky at 100
            img = 100.0 + noise
            add_gaussian_spot(img, x, y, snr, sigma)
            residual = suppress_background(img.astype(np.float32), 5, "opening")
        dets = detect(residual, region, det_cfg)
        thresholds.append(dets.threshold)
        if len(dets) == 0:
            continue
        dist = np.hypot(dets.xy[:, 0] - x, dets.xy[:, 1] - y)
        i = int(np.argmin(dist))
        if dist[i] > match_radius:
            continue
        detected += 1
        size = int(max(9, max(dets.bbox[i, 2], dets.bbox[i, 3]) + 4))   # as GEWCTracker._measure
        for m in methods:
            r = measure(residual, dets.labels, int(dets.component[i]), tuple(dets.xy[i]), size,
                        dets.threshold, m)
            if r is None:
                failed[m] += 1
                continue
            errors[m].append(float(np.hypot(r.x - x, r.y - y)))
        cx, cy = position_crb(snr, sigma, 1.0, x - round(x), y - round(y))
        crb2.append(cx * cx + cy * cy)
    res = CaseResult(snr, sigma, samples, detected, failed=failed)
    for m in methods:
        e = np.asarray(errors[m])
        res.rms[m] = float(np.sqrt(np.mean(e * e))) if e.size else float("nan")
        res.p95[m] = float(np.percentile(e, 95)) if e.size else float("nan")
    res.crb = float(np.sqrt(np.mean(crb2))) if crb2 else float("nan")
    res.threshold = float(np.mean(thresholds))
    return res


def bias_floor(snr: float, sigma: float, samples: int, seed: int, threshold: float = 4.0,
               methods: tuple[str, ...] = METHODS) -> dict[str, float]:
    """RMS error without noise (systematic error vs sub-pixel position), fixed ``threshold``.

    The threshold is what mean + 4·std gives on the noisy frames (≈ 4 σ_n); spots whose
    peak pixel stays below it are skipped.
    """
    import cv2

    rng = np.random.default_rng([seed, 7, round(snr * 100), round(sigma * 100)])
    err: dict[str, list[float]] = {m: [] for m in methods}
    for _ in range(samples):
        x, y = 12 + rng.uniform(-0.5, 0.5, size=2)
        res = np.zeros((25, 25))
        add_gaussian_spot(res, x, y, snr, sigma)
        _, labels = cv2.connectedComponents((res > threshold).astype(np.uint8), connectivity=8)
        comp = int(labels[round(y), round(x)])
        if comp == 0:
            continue
        for m in methods:
            r = measure(res, labels, comp, (x, y), 9, threshold, m)
            if r is not None:
                err[m].append(float(np.hypot(r.x - x, r.y - y)))
    return {m: float(np.sqrt(np.mean(np.square(e)))) if e else float("nan") for m, e in err.items()}


def markdown_table(results: list[CaseResult], methods: tuple[str, ...] = METHODS) -> str:
    """Rows SNR × σ: detection rate, RMS error per method, CRB, GEWC/CRB and improved/CRB."""
    head = (["peak SNR", "σ (px)", "detected"] + [f"{LABELS[m]} RMS" for m in methods]
            + ["CRB", "GEWC / CRB", "improved / CRB"])
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in results:
        cells = [f"{r.snr:g}", f"{r.sigma:g}", f"{100 * r.detection_rate:.0f} %"]
        for m in methods:
            note = f" ({r.failed[m]} failed)" if r.failed.get(m) else ""
            cells.append(f"{r.rms[m]:.3f}{note}" if r.detected else "–")
        if r.detected:
            cells += [f"{r.crb:.3f}", f"{r.rms.get('gewc', np.nan) / r.crb:.2f}",
                      f"{r.rms.get('gewc-weighted', np.nan) / r.crb:.2f}"]
        else:
            cells += ["–", "–", "–"]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def plot(results: list[CaseResult], path: Path, methods: tuple[str, ...] = METHODS,
         title: str = "") -> None:
    """RMS error vs peak SNR, one panel per σ, log-log, with the CRB and the 1.5×CRB goal."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import matplotlib.ticker

    sigmas = sorted({r.sigma for r in results})
    fig, axes = plt.subplots(1, len(sigmas), figsize=(4.2 * len(sigmas), 4.0), sharey=True,
                             squeeze=False)
    style = {"gewc": ("C3", "o"), "gewc-weighted": ("C2", "s"), "intensity": ("C0", "^"),
             "gaussian": ("C1", "D")}
    for ax, s in zip(axes[0], sigmas):
        rows = sorted((r for r in results if r.sigma == s and r.detected), key=lambda r: r.snr)
        snr = np.array([r.snr for r in rows])
        crb = np.array([r.crb for r in rows])
        for m in methods:
            c, mk = style.get(m, ("k", "."))
            ax.plot(snr, [r.rms[m] for r in rows], marker=mk, color=c, label=LABELS[m])
        ax.plot(snr, crb, "k-", lw=2, label="Cramér–Rao bound")
        ax.plot(snr, 1.5 * crb, "k:", label="1.5 × CRB (goal)")
        strip = ax.get_xaxis_transform()          # x in data, y in axes fraction
        ax.text(snr[0], 0.09, "detected:", transform=strip, fontsize=7, color="0.35")
        for r in rows:
            ax.text(r.snr, 0.03, f"{100 * r.detection_rate:.0f}%", transform=strip, ha="center",
                    fontsize=7, color="0.35")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xticks(snr, [f"{v:g}" for v in snr])
        ax.xaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
        ax.set_ylim(0.02, 1.5)
        ax.set_xlabel("peak SNR (peak / σ_noise)")
        ax.set_title(f"spot σ = {s:g} px")
        ax.grid(True, which="both", alpha=0.3)
    axes[0][0].set_ylabel("RMS position error (px)")
    axes[0][-1].legend(fontsize=7, loc="upper right")
    if title:
        fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--samples", type=int, default=2000, help="frames per (SNR, σ) case")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--snr", type=float, nargs="+", default=list(SNRS))
    ap.add_argument("--sigma", type=float, nargs="+", default=list(SIGMAS))
    ap.add_argument("--background", choices=("known", "tophat"), default="known",
                    help="residual = frame - known background, or the 5x5 top-hat")
    ap.add_argument("--k-sigma", type=float, default=4.0, help="detection threshold mean + k·std")
    ap.add_argument("--frame", type=int, default=256,
                    help="frame side (px); large enough that the spot barely moves mean + k·std")
    ap.add_argument("--methods", nargs="+", default=list(METHODS), choices=METHODS)
    ap.add_argument("--bias-floor", type=int, default=200, metavar="N",
                    help="noise-free spots per case for the systematic-error table (0: skip)")
    ap.add_argument("--plot", type=Path, default=ROOT / "docs" / "images" / "centroid_accuracy.png")
    ap.add_argument("--no-plot", action="store_true")
    ap.add_argument("--json", type=Path, help="also write the results as JSON")
    args = ap.parse_args(argv)
    methods = tuple(args.methods)
    t0 = time.perf_counter()
    results = []
    for s in args.sigma:
        for snr in args.snr:
            results.append(run_case(snr, s, args.samples, args.seed, args.background,
                                    frame=args.frame, k_sigma=args.k_sigma, methods=methods))
            print(f"σ {s:g} SNR {snr:g}: {time.perf_counter() - t0:.0f} s", file=sys.stderr)
    results.sort(key=lambda r: (r.snr, r.sigma))
    print(markdown_table(results, methods))
    if args.bias_floor:
        print("\nNoise-free systematic error (RMS over sub-pixel positions, threshold 4):\n")
        print("| peak SNR | σ (px) | " + " | ".join(LABELS[m] for m in methods) + " |")
        print("|" + "---|" * (len(methods) + 2))
        for r in results:
            b = bias_floor(r.snr, r.sigma, args.bias_floor, args.seed, methods=methods)
            cells = [f"{b[m]:.3f}" if np.isfinite(b[m]) else "not detected" for m in methods]
            print(f"| {r.snr:g} | {r.sigma:g} | " + " | ".join(cells) + " |")
    thr = [r.threshold for r in results]
    print(f"\nmean detection threshold: {min(thr):.2f} … {max(thr):.2f} σ_n over the cases")
    elapsed = time.perf_counter() - t0
    print(f"\n{args.samples} samples per case, seed {args.seed}, background {args.background}, "
          f"{args.frame}x{args.frame} frames, k_sigma {args.k_sigma:g}: {elapsed:.0f} s")
    if not args.no_plot:
        plot(results, args.plot, methods,
             f"{args.samples} spots per point, background {args.background}, "
             f"threshold mean + {args.k_sigma:g}·std")
        print(f"plot: {args.plot}")
    if args.json:
        args.json.write_text(json.dumps([asdict(r) for r in results], indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
