"""What several parts of the comparison share: the record's schema (data_formats/compare.md)
and the relative errors of the fit statistics (fitlab/metrics.py: the one rule)."""

from __future__ import annotations

from fitlab.metrics import relative_errors  # noqa: F401  (the fit statistics' rule)

SCHEMA = "fitlab-compare"
SCHEMA_VERSION = 1
