"""Figures for the kinematics part of the lab (filled in by its module's work)."""
