"""The defaults of text queries, shared by the method's SemanticScene, the scene loader, cinesplat-plan's options and
the viewers. Torch-free, so cinesplat-plan checks its options before torch loads."""

# Relevancy above which a selected Gaussian counts toward the object's centre (SemanticScene.centre_relevancy). 0.65 was
# chosen on synthetic rooms 0 and 1 and then checked on rooms 2 and 4, trained afterwards: room 4's bookshelf 7.96% ->
# 0.67% of the room off, room 2's worst object 1.31 -> 1.39% (benchmarks/RESULTS.md has the sweep).
CENTRE_RELEVANCY = 0.65
# What text queries use unless told otherwise (cinesplat-plan's --semantic-smoothing / --object-cluster, the viewers):
SMOOTH_NEIGHBORS = 32  # each Gaussian's latent averaged over this many nearest Gaussians (once per scene)
OBJECT_CLUSTER = 0.02  # a target is the heaviest cluster of its Gaussians, binned at this fraction of the scene extent
