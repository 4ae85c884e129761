"""Exact geometric queries: ellipsoid intersection, point and segment clearance, sight lines.

Modules: clearance_queries, collision, distance, distance_fused, native_scene, occlusion, ranges, voxel_traversal.
"""
