"""The pure simulator: design spaces, city layout, meshes, texture banks, EXR tiles, design presets,
render quality presets and previews. numpy and OpenImageIO only; exactly what the Blender add-on
ships besides ``blender`` and ``render``."""
