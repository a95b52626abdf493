"""The render engine: the RenderEngine class, F12/animation renders, the viewport, depsgraph -> kernels scene sync."""
