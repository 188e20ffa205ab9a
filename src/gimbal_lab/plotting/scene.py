"""Figures for the scene part of the lab (filled in by its module's work)."""
