"""Figures for the control part of the lab (filled in by its module's work)."""
