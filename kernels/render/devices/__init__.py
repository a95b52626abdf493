"""The device layer: the Device base and registry, the CPU device, the frame, its set-up,
the band loop, the table of modes."""
