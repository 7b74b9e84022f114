"""wfviz: wide-field IR small-target tracking, every stage recorded to Rerun."""

__version__ = "0.1.0"
