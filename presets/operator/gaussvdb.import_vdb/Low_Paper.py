import bpy
op = bpy.context.active_operator

op.lods = {'low'}
op.weights = 'paper'
op.level_set_band = True
