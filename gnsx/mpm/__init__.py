"""The reference solver: 2D MLS-MPM water with walls and ramps, WaterRamps-like scenes, dataset generation.

Modules: :mod:`~gnsx.mpm.solver` (the MLS-MPM solver), :mod:`~gnsx.mpm.scenes` (scene data, sampler,
particles), :mod:`~gnsx.mpm.presets` (dataset recipes), :mod:`~gnsx.mpm.generate` (trajectories and datasets).
Import from the modules; this package file stays light so ``import gnsx.mpm`` does not start simulations.
"""
