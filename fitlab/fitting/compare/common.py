"""What several parts of the comparison share: the record's schema (data_formats/compare.md)."""

from __future__ import annotations

SCHEMA = "fitlab-compare"
SCHEMA_VERSION = 2
#: Versions load_compare reads (1: before channels[c].models[k].statuses).
READABLE_VERSIONS = (1, 2)
