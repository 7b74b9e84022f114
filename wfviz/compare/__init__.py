"""``wfviz compare``: several trackers or configurations over one clip, in one recording on one
timeline, with the frames where they disagree marked. Pure: no rerun here (the recording is
:mod:`wfviz.record.compare`). The comparison itself runs in :mod:`wfviz.compare.session` (not
imported here: it opens the recording, which imports this package's pure parts)."""

from wfviz.compare.differences import KINDS, Disagreements, FrameComparison, Mark, RunFrame
from wfviz.compare.runs import RunGroup, RunSpec, check_fit, check_labels, make_trackers, parse_run, study_runs
from wfviz.compare.summary import CompareSummary, Comparison, RunOutcome, format_summary, summarize

__all__ = ["KINDS", "CompareSummary", "Comparison", "Disagreements", "FrameComparison", "Mark", "RunFrame",
           "RunGroup", "RunOutcome", "RunSpec", "check_fit", "check_labels", "format_summary", "make_trackers", "parse_run",
           "study_runs", "summarize"]
