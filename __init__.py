"""Blender extension entry point (the zip's root package); the add-on itself is in ``blender_addon/``."""

from .blender_addon import register, unregister

__all__ = ["register", "unregister"]
