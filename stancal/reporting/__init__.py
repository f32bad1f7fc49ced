"""Figures and written reports."""
