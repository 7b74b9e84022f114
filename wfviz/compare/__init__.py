"""``wfviz compare``: several trackers or configurations over one clip, in one recording on one
timeline, with the frames where they disagree marked. Pure: no rerun here (the recording is
:mod:`wfviz.record.compare`)."""

from wfviz.compare.differences import KINDS, Disagreements, FrameComparison, Mark, RunFrame
from wfviz.compare.runs import RunSpec, check_labels, make_trackers, parse_run, study_runs
from wfviz.compare.session import CompareSummary, RunOutcome, compare, format_summary

__all__ = ["KINDS", "CompareSummary", "Disagreements", "FrameComparison", "Mark", "RunFrame", "RunOutcome",
           "RunSpec", "check_labels", "compare", "format_summary", "make_trackers", "parse_run", "study_runs"]
