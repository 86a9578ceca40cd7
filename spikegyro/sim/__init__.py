"""Event-camera simulator (ESIM-style) and dataset generator."""
