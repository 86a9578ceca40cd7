"""Metrics, per-speed bins, figures and reports."""
