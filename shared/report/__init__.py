"""The reproduction report: the paper's Table 3, Fig. 19 and Fig. 24, and linemap against a
line-segment EKF-SLAM baseline on simulated worlds and the SLAM benchmark logs (``linemap report``)."""

from shared.report.build import ReportResults, ReportSettings, run_report, run_worlds_report

__all__ = ["ReportResults", "ReportSettings", "run_report", "run_worlds_report"]
