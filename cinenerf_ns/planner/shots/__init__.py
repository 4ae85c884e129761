"""Shots end to end: the Planner facade, one leg's stages, candidates, multi-stop, scoring, export.

Modules: camera_path, candidate_scores, candidates, multistop, plan_request, planner, prepared_scene, safety, scoring,
shot, stages, workers.
"""
