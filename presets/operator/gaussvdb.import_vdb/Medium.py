import bpy
op = bpy.context.active_operator

op.lods = {'medium'}
op.weights = 'field'
op.level_set_band = True
