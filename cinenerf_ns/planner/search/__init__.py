"""Where a shot may go: goal and start positions, voxel paths, line-of-sight shortcuts.

Modules: astar, coarse_path, goal, reach, shortcut, starts.
"""
