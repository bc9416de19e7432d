"""Figures and HTML reports. The only package of fitlab that imports matplotlib (Agg backend)."""

from fitlab.report.build import build_report  # noqa: E402

__all__ = ["build_report"]
