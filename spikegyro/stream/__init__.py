"""Stateful, event-driven streaming inference for real-time prediction."""
