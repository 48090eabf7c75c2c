"""Ember: a physically based path tracer for Blender, in NumPy and Embree.

The add-on's entry point. Blender modules are imported inside register(), so `ember.kernels`
(the path tracer) imports without bpy, as the tests and the command line need.
"""


def register():
    from . import engine
    engine.register()


def unregister():
    from . import engine
    engine.unregister()
