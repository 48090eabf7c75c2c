"""Participating media (docs/architecture.md, Where new content goes):

    medium       Media: the scene's media (a material's Volume output inside an object, the world's), majorants
    tracking     distance sampling by null scattering, transmittance
    channels     the colour channel distance sampling follows
    stage        the path loop's medium stages: segments, the scattering vertex, the volume stack's crossings
    stack        the volume stack
    scatter      a point's phase closures as one mixture
    phase        Cycles' phase functions (Henyey-Greenstein, Fournier-Forand, Draine, Rayleigh; Mie's fit)
    equiangular  equiangular distance sampling toward a light, spot cones
    grid         voxel grids (Volume objects, smoke domains)
"""
