"""`meta-sim`: the command line. It only parses options and calls the modules that do the work.

``base`` holds the command group; each other module adds its commands to it when imported here.
"""

from . import bench, export, jobs, learn, render, task, textures  # noqa: F401  (each registers its commands)
from .base import main

__all__ = ["main"]
