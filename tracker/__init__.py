"""Trackers: they publish vs/<fleet>/pose/<robot> (simulated VGPS for now)."""
