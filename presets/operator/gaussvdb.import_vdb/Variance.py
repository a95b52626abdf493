import bpy
op = bpy.context.active_operator

op.lods = {'variance'}
op.weights = 'field'
op.level_set_band = True
