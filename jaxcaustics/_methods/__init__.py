"""Caustic methods; each turns a scene into an irradiance image."""
