"""Rendering: the render options and their planning into jobs, the render loop that turns jobs into
EXR tiles through ``meta_sim.blender``, and the headless worker entry point. No torch."""
