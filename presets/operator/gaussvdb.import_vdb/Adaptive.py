import bpy
op = bpy.context.active_operator

op.lods = {'adaptive'}
op.tolerance = 0.02
op.weights = 'field'
op.level_set_band = True
