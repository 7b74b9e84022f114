"""Gaussian-fit centroid, Cramér–Rao bound and the improved GEWC variant ("gewc-weighted")."""

from __future__ import annotations

import math

import numpy as np
import pytest

from wfviz.config import ConfigError, config_from_dict
from wfviz.stages.centroid import (
    gaussian_fit,
    gaussian_model,
    gewc_weighted_centroid,
    measure,
    position_crb,
)
from wfviz.synth.psf import add_gaussian_spot, gaussian_spot_image
from wfviz.trackers.gewc.config import GEWCConfig

NEW_METHODS = ("gewc-weighted", "gaussian")


@pytest.mark.parametrize("sigma", [0.5, 1.0, 1.5])
def test_gaussian_fit_recovers_noise_free_sub_pixel_position(sigma):
    rng = np.random.default_rng(11)
    for _ in range(5):
        x, y = 6 + rng.uniform(-0.5, 0.5, size=2)
        img = gaussian_spot_image((13, 13), x, y, 20.0, sigma) + 3.0
        fit = gaussian_fit(img, start=(6.0, 6.0))
        assert fit is not None
        assert math.hypot(fit.x - x, fit.y - y) < 0.01
        assert abs(fit.sigma - sigma) < 0.01 and abs(fit.background - 3.0) < 0.01


def test_gaussian_model_matches_the_synthetic_psf_and_its_jacobian():
    p = np.array([7.0, 5.3, 4.8, 1.1, 0.4])
    mu, jac = gaussian_model((11, 12), p)
    assert np.allclose(mu, gaussian_spot_image((11, 12), 5.3, 4.8, 7.0, 1.1) + 0.4, atol=1e-12)
    for i in range(5):
        d = np.zeros(5)
        d[i] = 1e-6
        num = (gaussian_model((11, 12), p + d)[0] - gaussian_model((11, 12), p - d)[0]) / 2e-6
        assert np.allclose(num.ravel(), jac[:, i], atol=1e-6)


@pytest.mark.parametrize("sigma", [3.0, 4.0])
def test_crb_matches_the_well_sampled_analytic_bound(sigma):
    """σ ≫ 1 px: std per axis → √(2/π)·σ_n/peak, for any σ and with unknown peak/σ/background."""
    reference = math.sqrt(2.0 / math.pi) * 2.0 / 25.0
    for d in (0.0, 0.3):
        sx, sy = position_crb(25.0, sigma, 2.0, d, d)
        assert abs(sx / reference - 1) < 0.10 and abs(sy / reference - 1) < 0.10
        assert abs(sx / (reference * (1 + 1 / (12 * sigma**2))) - 1) < 0.01   # box-blur correction


def test_crb_scales_with_noise_over_peak():
    a = position_crb(10.0, 1.0, 1.0, 0.2, -0.1)
    b = position_crb(20.0, 1.0, 2.0, 0.2, -0.1)
    assert np.allclose(a, b)
    assert position_crb(10.0, 1.0, 1.0)[0] > position_crb(20.0, 1.0, 1.0)[0]


def _rms_at_snr(snr: float, n: int = 150, seed: int = 5) -> dict[str, float]:
    """RMS radial error of each method, σ = 1 spots in σ_n = 1 noise, threshold 4 (≈ mean + 4·std)."""
    rng = np.random.default_rng(seed)
    methods = ("gewc", "gewc-weighted")
    err: dict[str, list[float]] = {m: [] for m in methods}
    for _ in range(n):
        x, y = 10 + rng.uniform(-0.5, 0.5, size=2)
        img = rng.normal(0.0, 1.0, (21, 21))
        add_gaussian_spot(img, x, y, snr, 1.0)
        labels = (img > 4.0).astype(np.int32)
        if labels[round(y), round(x)] == 0:
            continue
        for m in methods:
            r = measure(img, labels, 1, (x, y), 9, 4.0, m)
            err[m].append(math.hypot(r.x - x, r.y - y))
    return {m: float(np.sqrt(np.mean(np.square(e)))) for m, e in err.items()}


def test_improved_gewc_beats_faithful_gewc_at_snr_10():
    rms = _rms_at_snr(10.0)
    assert rms["gewc-weighted"] < 0.7 * rms["gewc"]
    assert rms["gewc-weighted"] < 0.2      # CRB ≈ 0.12 px here


def test_improved_gewc_noise_free_and_ignores_other_targets():
    res = np.zeros((30, 30))
    add_gaussian_spot(res, 12.3, 14.6, 50.0, 1.0)
    add_gaussian_spot(res, 17.5, 14.0, 50.0, 1.0)
    labels = np.zeros((30, 30), np.int32)
    labels[res > 2.0] = 1
    labels[:, 15:][labels[:, 15:] == 1] = 2
    r = measure(res, labels, 1, (12, 15), 11, 2.0, "gewc-weighted")
    assert math.hypot(r.x - 12.3, r.y - 14.6) < 0.02
    assert r.weights.shape == (8,) and abs(r.weights.sum() - 1) < 1e-9
    assert np.allclose(r.weights[:4], r.weights[4:])       # opposite octants share a weight
    assert gewc_weighted_centroid(np.zeros((5, 5)), np.zeros((5, 5))) is None


@pytest.mark.parametrize("method", NEW_METHODS)
def test_measure_and_config_accept_every_new_method(method):
    res = np.zeros((25, 25), np.float32)
    add_gaussian_spot(res, 11.4, 12.7, 30.0, 1.2)
    labels = (res > 3.0).astype(np.int32)
    r = measure(res, labels, 1, (11.4, 12.7), 9, 3.0, method)
    assert r is not None and math.hypot(r.x - 11.4, r.y - 12.7) < 0.05
    assert r.weights.shape == (8,)
    assert config_from_dict({"centroid": {"method": method}}, GEWCConfig).centroid.method == method


def test_faithful_gewc_stays_the_default():
    assert config_from_dict({}, GEWCConfig).centroid.method == "gewc"
    with pytest.raises(ConfigError):
        config_from_dict({"centroid": {"method": "gauss"}}, GEWCConfig)
