"""Figures for the camera part of the lab (filled in by its module's work)."""
