"""The only code that imports ``bpy``: turns a layout and a design into a Blender scene and renders it."""
