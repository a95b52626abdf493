import bpy
settings = bpy.context.scene.gaussvdb

settings.colormap = 'coolwarm'
