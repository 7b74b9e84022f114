"""Stages of the star-field tracker (METHODS.md §3): segmentation into star points, star
pairing and registration, target chains, and the paper's detection metrics. Composed by
:mod:`wfviz.trackers.starfield`; pure numpy / OpenCV / SciPy, no rerun."""
