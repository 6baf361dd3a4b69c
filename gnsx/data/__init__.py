"""Datasets: gnsx's on-disk format and its store (:mod:`~gnsx.data.store`), metadata, checks, readers for the
formats users hold (DeepMind's TFRecord, HDF5, npz: :mod:`~gnsx.data.formats`), the LightningDataModule that
streams training samples (:mod:`~gnsx.data.datamodule`), rollout files (:mod:`~gnsx.data.rollout_io`) and
DeepMind's WaterRamps facts (:mod:`~gnsx.data.waterramps`). ``python -m gnsx.data`` generates, converts and
inspects datasets (its CLI is the one place here that calls the MPM solver in :mod:`gnsx.mpm`)."""
