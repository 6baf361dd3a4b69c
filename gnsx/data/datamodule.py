"""LightningDataModule: random training frames and whole validation/test trajectories from a gnsx dataset.

Training samples are single frames drawn uniformly over all trajectories of the train split (DeepMind's
scheme): frame ``k`` of trajectory ``t`` gives the model the positions ``p[k-H..k]``
(``H`` = velocity history)
and the target ``p[k+1]``. Velocities and accelerations are derived on the fly from these ``H + 2`` contiguous
frames, so the dataset on disk holds positions only (one memory-mapped read per sample).
"""

from __future__ import annotations

from pathlib import Path

import lightning as L
import numpy as np
import torch
from torch.utils.data import DataLoader, Dataset
from torch_geometric.data import Batch, Data

from gnsx.data.metadata import Metadata
from gnsx.data.store import SplitReader, load_metadata, open_split
from gnsx.data.trajectory import Trajectory


class FrameDataset(Dataset):
    """Every usable frame of a split as one sample.

    A sample is a PyG ``Data`` with ``position_sequence [N, H+1+lead, D]`` (oldest first), ``next_position
    [N, D]`` and ``particle_type [N]``; ``Batch`` concatenates samples and adds ``batch [sum N]``.
    """

    def __init__(self, reader: SplitReader, history: int, lead: int = 0):
        self.reader = reader
        self.history = history
        self.lead = lead
        # The model's H + 1 input frames, ``lead`` frames it predicts itself before the last loss step (the
        # pushforward trick and the unrolled loss, gnsx.model.training_targets.noisy_training_rollout), and the target.
        frames = history + 1 + lead
        counts = np.array([max(reader.num_frames(i) - frames, 0) for i in range(len(reader))], np.int64)
        if counts.sum() == 0:
            raise ValueError(f"{reader.root}: no trajectory has more than {frames} frames")
        self.cumulative = np.cumsum(counts)

    def __len__(self) -> int:
        return int(self.cumulative[-1])

    def __getitem__(self, index: int) -> Data:
        traj_index = int(np.searchsorted(self.cumulative, index, side="right"))
        first = index - (self.cumulative[traj_index - 1] if traj_index > 0 else 0)
        traj = self.reader[traj_index]
        # Frames first .. first+H+1+lead: the inputs and the target; one contiguous slice of the memmap.
        last = first + self.history + self.lead + 2
        window = torch.from_numpy(np.array(traj.position[first:last], dtype=np.float32))
        return Data(
            position_sequence=window[:-1].transpose(0, 1).contiguous(),
            next_position=window[-1],
            particle_type=torch.from_numpy(np.array(traj.particle_type, dtype=np.int64)),
            num_nodes=window.shape[1],
        )


class TrajectoryDataset(Dataset):
    """Whole trajectories of a split (for rollouts): ``position [T, N, D]``, ``particle_type [N]`` tensors."""

    def __init__(self, reader: SplitReader, max_trajectories: int | None = None):
        self.reader = reader
        self.size = len(reader) if max_trajectories is None else min(len(reader), max_trajectories)

    def __len__(self) -> int:
        return self.size

    def __getitem__(self, index: int) -> dict:
        if not 0 <= index < self.size:  # also ends plain iteration at max_trajectories
            raise IndexError(f"trajectory {index} out of range (0..{self.size - 1})")
        traj: Trajectory = self.reader[index]
        return {
            "position": torch.from_numpy(np.array(traj.position, dtype=np.float32)),
            "particle_type": torch.from_numpy(np.array(traj.particle_type, dtype=np.int64)),
            "index": index,
        }


def _single(items: list):
    """Rollout loaders use batch size 1 and yield the trajectory itself."""
    return items[0]


class ParticleDataModule(L.LightningDataModule):
    """Streams a gnsx-format dataset (see :mod:`gnsx.data.store`).

    Args:
        root: dataset folder with ``metadata.json`` and split folders.
        history: velocity frames the model reads (1 simplified, 5 original).
        batch_size: graphs per training batch (paper: 2).
        num_workers: DataLoader worker processes for training frames.
        val_max_trajectories: validation rollouts per validation run (None: all).
        test_max_trajectories: test rollouts (None: all).
        pushforward_steps: model steps without gradient before the loss (the pushforward trick,
            ``train.pushforward_steps``; 0: DeepMind's single step).
        unroll_steps: model steps the loss runs over, with the gradient through them (``train.unroll_steps``;
            1: DeepMind's single step). A training sample holds ``pushforward_steps + unroll_steps - 1`` frames
            beyond the model's inputs and target.
    """

    def __init__(
        self,
        root: str | Path,
        history: int = 1,
        batch_size: int = 2,
        num_workers: int = 0,
        val_max_trajectories: int | None = None,
        test_max_trajectories: int | None = None,
        pushforward_steps: int = 0,
        unroll_steps: int = 1,
    ):
        super().__init__()
        if unroll_steps < 1:
            raise ValueError(f"ParticleDataModule: unroll_steps must be >= 1, got {unroll_steps}")
        self.root = Path(root)
        self.history = history
        self.batch_size = batch_size
        self.num_workers = num_workers
        self.val_max_trajectories = val_max_trajectories
        self.test_max_trajectories = test_max_trajectories
        self.pushforward_steps = pushforward_steps
        self.unroll_steps = unroll_steps
        self._metadata: Metadata | None = None
        self._checked: dict[str, SplitReader] = {}

    @property
    def metadata(self) -> Metadata:
        """Dataset facts (bounds, radius, dim, statistics) that configure the model."""
        if self._metadata is None:
            self._metadata = load_metadata(self.root)
        return self._metadata

    def check(self, splits: list[str]) -> None:
        """Open ``splits`` and check them against the metadata (dimension) and for NaN/Inf positions
        (:func:`~gnsx.data.store.open_split`), before training starts.

        Raises:
            DataError: naming the metadata or positions file, trajectory, frame and particle.
        """
        for split in splits:
            self._checked[split] = open_split(self.root, split, self.metadata)

    def _reader(self, split: str) -> SplitReader:
        """A checked reader of ``split`` (checked now unless :meth:`check` did)."""
        if split not in self._checked:
            self.check([split])
        return self._checked[split]

    def setup(self, stage: str | None = None) -> None:
        if stage in (None, "fit"):
            self.train_set = FrameDataset(
                self._reader("train"), self.history, self.pushforward_steps + self.unroll_steps - 1
            )
            self.val_set = TrajectoryDataset(self._reader("valid"), self.val_max_trajectories)
        if stage in (None, "test"):
            self.test_set = TrajectoryDataset(self._reader("test"), self.test_max_trajectories)

    def train_dataloader(self) -> DataLoader:
        return DataLoader(
            self.train_set,
            batch_size=self.batch_size,
            shuffle=True,
            num_workers=self.num_workers,
            collate_fn=Batch.from_data_list,
            persistent_workers=self.num_workers > 0,
            drop_last=True,
        )

    def val_dataloader(self) -> DataLoader:
        return DataLoader(self.val_set, batch_size=1, collate_fn=_single)

    def test_dataloader(self) -> DataLoader:
        return DataLoader(self.test_set, batch_size=1, collate_fn=_single)
