"""What to draw: the scene, camera, transfer functions, colormaps, lights, clipping, legend."""
