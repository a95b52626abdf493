"""The GPU device's tables (numpy) and its GLSL (glsl/), with the one assembly of a shader for
Blender's gpu module and for plain OpenGL."""
