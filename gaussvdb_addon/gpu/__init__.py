"""The GPU device on Blender's ``gpu`` module: compute shaders (compute), running them in a GPU
context (context), whether one can be had (probe), the device (device)."""
