"""Meta-Sim for Blender: build procedural cities, browse inferred designs with thumbnails, apply them.

Package layout. Blender installs the extension zip as one Python package
(``bl_ext.<repository>.meta_sim``) whose root holds ``__init__.py`` and the
manifest. The repository's top level is that root: its ``__init__.py`` only
re-exports ``register``/``unregister`` from this ``blender_addon`` subpackage,
and the pure ``meta_sim`` modules the add-on needs (design space, layout,
meshes, presets, texture banks, the Blender scene builder) ship beside it as
the ``meta_sim`` subpackage, imported relatively (``from ..meta_sim import``).
So the add-on runs the very code the command line and the render farm run,
and the manifest's ``[build] paths`` lists exactly those files: no torch side,
CLI or tests in the zip.

Modules: ``preferences`` (the add-on's preferences), ``properties`` (scene settings), ``library`` (texture bank and
design space), ``previews`` (thumbnails), ``city`` (the city in the user's
file), ``presets_ui`` (preset rows and their list), ``assets`` and ``assets_ui`` (the presets as an
asset library: Asset Browser, asset shelf), ``tasks`` (long operations: progress, Esc), ``operators``,
``panels``.
"""

from __future__ import annotations

import bpy

from . import assets_ui, library, operators, panels, preferences, presets_ui, previews, properties

CLASSES = (*preferences.CLASSES, *properties.CLASSES, *presets_ui.CLASSES, *operators.CLASSES, *assets_ui.CLASSES,
           *panels.CLASSES)


def register() -> None:
    for cls in CLASSES:
        bpy.utils.register_class(cls)
    properties.register()
    previews.register()
    assets_ui.register()


def unregister() -> None:
    assets_ui.unregister()
    previews.unregister()
    properties.unregister()
    for cls in reversed(CLASSES):
        bpy.utils.unregister_class(cls)
    library.clear()
