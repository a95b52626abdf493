"""GaussVDB rendering kernels: cameras, transfer functions, colormaps, devices (no bpy)."""
from .devices.cpu_device import CPUDevice
from .devices.device import Device, available_devices, get_device, register_device
from .scene import clip
from .scene.camera import Camera, generate_rays
from .scene.colormaps import colormap, colormap_names, srgb_to_linear
from .scene.objects import MODES, RenderObject, RenderScene
from .scene.transfer import TransferFunction, value_range, voxel_stats

__all__ = ["clip", "Camera", "generate_rays", "colormap", "colormap_names", "srgb_to_linear", "CPUDevice",
           "Device", "available_devices", "get_device", "register_device", "MODES", "RenderObject",
           "RenderScene", "TransferFunction", "value_range", "voxel_stats"]
