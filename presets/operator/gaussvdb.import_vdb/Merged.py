import bpy
op = bpy.context.active_operator

op.lods = {'merged'}
op.weights = 'field'
op.level_set_band = True
