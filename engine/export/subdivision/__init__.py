"""Adaptive subdivision, as Cycles dices a mesh whose last modifier is an adaptive Subdivision Surface: the base
(cage) mesh, its limit surface as patches, DiagSplit's edge factors from the dicing camera, and EdgeDice's
triangles. Plain NumPy, no bpy: engine/export/adaptive.py reads Blender and hands these modules arrays.

    cage.py     Cage: the base mesh's faces, and its patches (one per quad, one per corner of other faces)
    refine.py   Catmull-Clark refinement of the cage, level by level, to regular grids of control points
    surface.py  LinearSurface (Simple) and CatmullClarkSurface: position and normal at (patch, u, v)
    dicing.py   DicingCamera: the world size of a pixel at a point (Cycles' Camera::world_to_raster_size)
    split.py    DiagSplit: patches split into subpatches with an edge factor per edge (subd/split.cpp)
    dice.py     EdgeDice: subpatches into vertices and triangles (subd/dice.cpp)
"""
