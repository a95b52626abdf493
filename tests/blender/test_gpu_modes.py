"""The GPU device's modes are the table's (kernels/render/devices/modes.py): it draws every mode whose row
has a GPU shader, with that shader, and a derived mode through the mode it is drawn as."""


def test_the_gpu_device_draws_the_tables_gpu_modes(addon):
    from bl_ext.user_default.gaussvdb.gaussvdb_addon.gpu import device
    from bl_ext.user_default.gaussvdb.kernels.render import available_devices
    from bl_ext.user_default.gaussvdb.kernels.render.devices import modes

    drawn = {m.name.lower() for m in modes.drawn_modes() if modes.spec(m).gpu is not None}
    assert set(device.MODES) == drawn == {"particles", "field", "paper", "reference"}
    assert all(device.MODES[n] is modes.spec(n).gpu for n in device.MODES)
    derived = set(modes.gpu_modes()) - drawn
    assert derived == {"splat"} and all(modes.spec(n).drawn_as.name.lower() in drawn for n in derived)
    assert available_devices()[0] == "CPU"  # registered first, the GPU (where usable) after it
