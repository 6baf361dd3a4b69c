"""Named constants shared across gnsx (DeepMind's `learning_to_simulate` conventions)."""

#: Number of particle types in DeepMind's datasets (ids 0..8).
NUM_PARTICLE_TYPES = 9
#: Static/kinematic particles (ramps, boundaries): no noise, not in the loss, never moved by the model.
KINEMATIC_PARTICLE_ID = 3
#: Water particles in WaterRamps.
WATER_PARTICLE_ID = 5
#: Human names of the ids DeepMind uses; other ids below NUM_PARTICLE_TYPES are valid but unnamed.
PARTICLE_TYPE_NAMES = {0: "rigid", 3: "boundary", 5: "water", 6: "sand", 7: "goop"}
#: Dataset splits in the order DeepMind ships them.
SPLITS = ("train", "valid", "test")
