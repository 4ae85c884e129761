"""The splat as obstacles: ellipsoids, their file formats, spatial index and voxel occupancy.

Modules: ellipsoids, occupancy, planning_region, ply, procedural, spatial_index, splat_params.
"""
