"""One colour per metric and per searched parameter, the same in ``study.rrd`` and the report's
plots (matplotlib's tab10 colours, so ``C0`` … ``C9`` name the same ones), and the marks of the
Pd / false-track plane."""

from __future__ import annotations

import colorsys

RGB = tuple[int, int, int]

#: matplotlib's tab10, C0 … C9
TAB10: tuple[RGB, ...] = (
    (31, 119, 180), (255, 127, 14), (44, 160, 44), (214, 39, 40), (148, 103, 189),
    (140, 86, 75), (227, 119, 194), (127, 127, 127), (188, 189, 34), (23, 190, 207),
)
#: the metrics' colours; a metric not named here gets one from :func:`metric_color`
METRIC_COLORS: dict[str, RGB] = {
    "mota": TAB10[0], "idf1": TAB10[1], "pd": TAB10[2], "fa": TAB10[3], "idsw": TAB10[4],
    "hota": TAB10[5], "deta": TAB10[6], "assa": TAB10[8],
}
#: marks of the plane: every trial, the defaults (trial 0), the best trial(s), the Pareto front,
#: the axes and their labels
TRIAL_COLOR: RGB = (150, 170, 215)
DEFAULTS_COLOR: RGB = (0, 210, 255)
BEST_COLOR: RGB = (255, 200, 0)
FRONT_COLOR: RGB = (230, 60, 60)
AXIS_COLOR: RGB = (225, 225, 225)


def metric_color(metric: str) -> RGB:
    """The colour of ``metric`` (a fixed one for the known metrics, else one from its name)."""
    if metric in METRIC_COLORS:
        return METRIC_COLORS[metric]
    return _hue(sum(ord(c) * 31**i for i, c in enumerate(metric)) % 97)


def param_color(index: int) -> RGB:
    """The colour of the ``index``-th parameter of a search space (tab10, then hue steps)."""
    return TAB10[index] if index < len(TAB10) else _hue(index)


def _hue(n: int) -> RGB:
    r, g, b = colorsys.hsv_to_rgb((n * 0.618033988749895) % 1.0, 0.7, 0.95)
    return int(r * 255), int(g * 255), int(b * 255)
