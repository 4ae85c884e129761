"""Safe flight corridors: convex polytopes in free space around a path.

Modules: corridor_options, grid_polytope, polytope, polytope_batched, polytope_native, polytope_planes, safe_corridor.
"""
