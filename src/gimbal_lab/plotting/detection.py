"""Figures for the detection part of the lab (filled in by its module's work)."""
