"""Figures for the study part of the lab (filled in by its module's work)."""
