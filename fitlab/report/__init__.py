"""Figures and HTML reports. The only package of fitlab that imports matplotlib (Agg backend)."""
