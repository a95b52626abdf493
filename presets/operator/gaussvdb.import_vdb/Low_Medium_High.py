import bpy
op = bpy.context.active_operator

op.lods = {'high', 'low', 'medium'}
op.weights = 'field'
op.level_set_band = True
