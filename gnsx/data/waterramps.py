"""DeepMind's WaterRamps dataset facts (its metadata.json): the domain, the connection radius, the particle
spacing, the velocity and acceleration statistics (per-frame differences, data units) and the particle count of
its largest scenes. gnsx times and sizes models at these facts when no data is at hand (speed needs no
training)."""

#: DeepMind's WaterRamps facts: domain, radius, spacing, statistics, particle count.
WATERRAMPS = {
    "bounds": [[0.1, 0.9], [0.1, 0.9]],
    "radius": 0.015,
    "spacing": 0.009,
    "particles": 2300,
    "vel_mean": [-6.14e-08, -7.43e-04],
    "vel_std": [2.24e-03, 2.27e-03],
    "acc_mean": [-1.71e-07, -2.14e-07],
    "acc_std": [1.68e-04, 1.82e-04],
}
