"""GaussVDB: OpenVDB volumes as Gaussian point clouds, rendered by a native SciVis ray marcher.

Registration only; everything else lives in gaussvdb_addon/, operators/ and kernels/.
"""

import sys

if "bpy" in locals():
    # Re-executed by "Reload Scripts": drop our submodules so the next import reads them afresh.
    for _name in [m for m in sys.modules if m.startswith(__name__ + ".")]:
        del sys.modules[_name]

import bpy  # noqa: E402,F401  (marks the module as loaded for the reload check above)


def register():
    from .gaussvdb_addon import registration

    registration.register()


def unregister():
    from .gaussvdb_addon import registration

    registration.unregister()
