"""Blender extension entry point (the zip's root package); the add-on itself is in ``blender_addon/``."""

if __package__:  # Blender imports this file as the extension's package; pytest may import it bare
    from .blender_addon import register, unregister

__all__ = ["register", "unregister"]
