"""The paper-reproduction report (``ff-reproduce``): sections, judging a plan, the written files."""
from ff_planner.report.reproduce import PAPER, SECTIONS, PaperValues, Report, coulomb_example, judge, run

__all__ = ["PAPER", "SECTIONS", "PaperValues", "Report", "coulomb_example", "judge", "run"]
