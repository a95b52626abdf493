"""The GPU device as the kernel tests' device, for their GPU twins (test_gpu_twins*.py)."""


class OnGPU:
    """The GPU device, failing any frame it hands to the CPU device."""

    arith_tol = 1e-4  # tolerance for pixels a test derives in float64 from the device's own (float32 math)

    def __init__(self, device):
        self.device = device

    def render(self, *args, **kw):
        out = self.device.render(*args, **kw)
        assert "fallback" not in self.device.stats, f"drawn by the CPU: {self.device.stats['fallback']}"
        assert self.device.stats.get("gpu"), "no GPU named in the stats"
        return out

    def __getattr__(self, name):
        return getattr(self.device, name)
