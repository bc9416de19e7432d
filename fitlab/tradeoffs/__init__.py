"""``fitlab tradeoffs``: what each accuracy knob costs in time, measured for one material in one
run (fitlab/tradeoffs/knobs.py lists the knobs; data_formats/tradeoffs_json.md the output)."""

from fitlab.tradeoffs.run import THRESHOLDS, Tradeoffs, recommend, tradeoffs

__all__ = ["THRESHOLDS", "Tradeoffs", "recommend", "tradeoffs"]
