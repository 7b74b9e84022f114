"""Stages of the star-field tracker (Gao Jianwei et al. 2012): segmentation into star points, star
pairing and registration, target chains, and the paper's detection metrics. Composed by
:mod:`wfviz.trackers.starfield`; pure numpy / OpenCV / SciPy, no rerun."""
