"""Inverse design: recover a scene's parameters from the caustics it casts."""
