"""The Blender glue: property groups, panels, presets, the render engine and the registration hub."""
