"""Everything that touches bpy: settings, panels, the RenderEngine, export, the progressive session.

Registration is an explicit ordered tuple: settings before the panels that draw them and the engine
that reads them; unregistered in reverse.
"""
from . import passes, properties, render_engine, ui

MODULES = (properties, passes, ui, render_engine)


def register():
    for module in MODULES:
        module.register()


def unregister():
    for module in reversed(MODULES):
        module.unregister()
    from ..kernels import workers
    workers.close_pool()    # idle worker processes would otherwise wait for their timeout
