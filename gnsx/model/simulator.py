"""The learned simulator: features + graph network + normalisation + semi-implicit Euler integration.

The simplified GNS of the paper and DeepMind's original GNS are two configurations of
:class:`LearnedSimulator` (constructor defaults = simplified):

==================  ===========  ===========================================================
argument            simplified   original GNS
==================  ===========  ===========================================================
latent_size         64           128
mp_steps            5            10
mlp_hidden_size     64           128
mlp_hidden_layers   1            2
history             1            5
type_encoding       "scalar"     "embedding" (type_embedding_size=16)
wall_clip           (0, 1)       (-1, 1)
edge_residual       False        True
self_edges          False        True (DeepMind's radius graph keeps i == j)
==================  ===========  ===========================================================

One switch changes what is computed, not the model (it is not architecture; changing it on a trained model
needs no retraining):

* ``cull`` (default on): exact culling (:mod:`gnsx.model.culling`). Only dynamic particles are decoded, and
  only the particles and edges their prediction depends on are computed, step by step. Their predictions
  are those of the full graph up to float rounding; static rows of :meth:`forward` are 0 instead of the
  (unused) values the decoder would give them. Exact for training too: the loss counts dynamic particles only.

(Approximate freezing of water at rest, which changes the results, is a rule of the layer above:
:mod:`gnsx.rules.freezing`, through :meth:`LearnedSimulator.predict_positions`' ``held``.)

The decoder is a third choice (``decoder``, architecture: it needs its own training):

* ``"node"`` (default, the paper's and DeepMind's): an MLP on each particle's latent gives its normalised
  acceleration.
* ``"pairwise"``: the acceleration is ``gravity + sum_j f_ij + gate_i w_i`` (data units per frame^2, scaled
  by ``acc_std``): antisymmetric pair forces ``f_ij = -f_ji`` from the edges into i
  (:class:`~gnsx.model.graph_network.PairwiseDecoder`), so interactions between water particles conserve
  momentum and a cluster in free flight falls exactly at ``gravity``; plus a per-particle wall force ``w_i``
  (the node decoder) switched on only within two radii of a wall (``gate_i``,
  :func:`gnsx.model.features.wall_contact_gate`).
  Static particles (ramps) exert pair forces too and are not pushed back: the ramp is an external body.

Time unit: one frame (dt = 1). Velocities and accelerations are per-frame differences of positions, the
units of the dataset statistics; the physical dt of the data (2.5 ms for WaterRamps) never enters.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import Tensor, nn

from gnsx.core.constants import KINEMATIC_PARTICLE_ID, NUM_PARTICLE_TYPES
from gnsx.model.config import check_config
from gnsx.model.culling import particles_in_reach
from gnsx.model.features import (
    edge_features,
    type_scalar_feature,
    velocity_features,
    wall_contact_gate,
    wall_features,
)
from gnsx.model.graph_network import EncodeProcessDecode
from gnsx.model.neighbors import radius_graph
from gnsx.model.padding import needs_padding


class LearnedSimulator(nn.Module):
    """Predicts per-particle normalised acceleration from a short window of positions.

    Args (keyword only):
        dim: spatial dimension D (2 for WaterRamps).
        bounds: ``[D][2]`` domain ``[lower, upper]`` per dimension (data units).
        radius: connectivity radius R (data units); also the unit of the wall and edge features.
        vel_mean, vel_std, acc_mean, acc_std: ``[D]`` training-set statistics of per-frame velocity and
            acceleration (dataset metadata).
        latent_size, mp_steps, mlp_hidden_size, mlp_hidden_layers: see :class:`EncodeProcessDecode`.
        history: number of velocities H the model reads (it reads ``H + 1`` positions).
        type_encoding: ``"scalar"`` (``type / 8``, one feature) or ``"embedding"`` (learned, per type).
        type_embedding_size: embedding size when ``type_encoding == "embedding"``.
        wall_clip: clip range of the wall-distance features (in units of R).
        edge_residual: residual edge latent update.
        layer_norm: LayerNorm after every MLP but the decoder.
        self_edges: connect every particle to itself in the radius graph.
        neighbor_search: ``"auto"``, ``"kdtree"`` or ``"cell"`` (see :func:`radius_graph`).
        cull: exact culling (module docstring); also settable on the model (``simulator.cull = False``).
        decoder: ``"node"`` or ``"pairwise"`` (module docstring).
        gravity: ``[D]`` the data's gravity, acceleration per frame^2 (data units,
            :func:`gnsx.evaluation.scoring.gravity_per_frame`): the pairwise decoder adds it to its forces; the
            node decoder's network ignores it, and the rules read it for either
            (:func:`gnsx.rules.scale.rules_gravity`). None: not recorded (node-decoder checkpoints before
            2026-12-07); the pairwise decoder then adds ``acc_mean`` (what the node decoder's zero output means).
        compile: ``torch.compile`` the network's blocks (:meth:`EncodeProcessDecode.compile_blocks`; fused
            C++ loops on CPU, needs a C++ compiler; the first frame or step compiles, ~10-60 s). Changes
            speed only, not the results (to float rounding) nor the parameters; docs/speed.md has figures.
        data_radius: the dataset's connectivity radius (data units), recorded with the data's other
            statistics; None: not recorded (checkpoints before it, which all used the data's radius). Not
            part of the network: the layer above reads it as the data's length scale
            (:func:`gnsx.rules.scale.rules_radius`), which differs from ``radius`` only when the model's graph
            has a radius of its own (``model.radius=0.05``).

    Attributes:
        input_frames: ``history + 1``, the number of position frames :meth:`forward` reads.
        config: the constructor arguments as plain Python values; ``LearnedSimulator(**config)`` rebuilds
            the model (store it in checkpoints next to the state_dict).
    """

    def __init__(
        self,
        *,
        dim: int,
        bounds: Sequence[Sequence[float]],
        radius: float,
        vel_mean: Sequence[float],
        vel_std: Sequence[float],
        acc_mean: Sequence[float],
        acc_std: Sequence[float],
        latent_size: int = 64,
        mp_steps: int = 5,
        mlp_hidden_size: int = 64,
        mlp_hidden_layers: int = 1,
        history: int = 1,
        type_encoding: str = "scalar",
        type_embedding_size: int = 16,
        wall_clip: Sequence[float] = (0.0, 1.0),
        edge_residual: bool = False,
        layer_norm: bool = True,
        self_edges: bool = False,
        neighbor_search: str = "auto",
        cull: bool = True,
        decoder: str = "node",
        gravity: Sequence[float] | None = None,
        compile: bool = False,
        data_radius: float | None = None,
    ):
        super().__init__()
        self.config = {
            "dim": int(dim),
            "bounds": [[float(v) for v in pair] for pair in bounds],
            "radius": float(radius),
            "vel_mean": [float(v) for v in vel_mean],
            "vel_std": [float(v) for v in vel_std],
            "acc_mean": [float(v) for v in acc_mean],
            "acc_std": [float(v) for v in acc_std],
            "latent_size": int(latent_size),
            "mp_steps": int(mp_steps),
            "mlp_hidden_size": int(mlp_hidden_size),
            "mlp_hidden_layers": int(mlp_hidden_layers),
            "history": int(history),
            "type_encoding": str(type_encoding),
            "type_embedding_size": int(type_embedding_size),
            "wall_clip": [float(v) for v in wall_clip],
            "edge_residual": bool(edge_residual),
            "layer_norm": bool(layer_norm),
            "self_edges": bool(self_edges),
            "neighbor_search": str(neighbor_search),
            "cull": bool(cull),
            "decoder": str(decoder),
            "gravity": None if gravity is None else [float(v) for v in gravity],
            "compile": bool(compile),
            "data_radius": None if data_radius is None else float(data_radius),
        }
        check_config(self.config)
        cfg = self.config
        self.dim = cfg["dim"]
        self.radius = cfg["radius"]
        self.history = cfg["history"]
        self.input_frames = self.history + 1
        self.wall_clip = tuple(cfg["wall_clip"])
        self.type_encoding = cfg["type_encoding"]
        self.self_edges = cfg["self_edges"]
        self.neighbor_search = cfg["neighbor_search"]
        # Buffers move with .to(device) and are saved in the state_dict, so a checkpoint carries its data.
        self.register_buffer("bounds", torch.tensor(cfg["bounds"], dtype=torch.float32))  # [D, 2]
        for name in ("vel_mean", "vel_std", "acc_mean", "acc_std"):
            self.register_buffer(name, torch.tensor(cfg[name], dtype=torch.float32))  # [D]
        self.decoder = cfg["decoder"]
        if self.decoder == "pairwise":
            # What the pairwise output adds to its forces, normalised: (gravity - acc_mean) / acc_std. Not in
            # the state_dict (checkpoints of the node decoder stay as they are); rebuilt from the config.
            gravity = self.acc_mean if cfg["gravity"] is None else torch.tensor(cfg["gravity"])
            self.register_buffer("free_fall", (gravity - self.acc_mean) / self.acc_std, persistent=False)

        if self.type_encoding == "embedding":
            self.type_embedding = nn.Embedding(NUM_PARTICLE_TYPES, cfg["type_embedding_size"])
            type_size = cfg["type_embedding_size"]
        else:
            self.type_embedding = None
            type_size = 1
        node_in = self.history * self.dim + 2 * self.dim + type_size
        edge_in = self.dim + 1
        self.network = EncodeProcessDecode(
            node_in=node_in,
            edge_in=edge_in,
            latent_size=cfg["latent_size"],
            mp_steps=cfg["mp_steps"],
            mlp_hidden_size=cfg["mlp_hidden_size"],
            mlp_hidden_layers=cfg["mlp_hidden_layers"],
            out_size=self.dim,
            edge_residual=cfg["edge_residual"],
            layer_norm=cfg["layer_norm"],
            decoder=self.decoder,
        )
        if cfg["compile"]:
            self.network.compile_blocks()

    # The switch lives in ``config`` so that ``LearnedSimulator(**config)`` rebuilds the model as it runs.
    @property
    def cull(self) -> bool:
        """Exact culling on (see the module docstring)."""
        return self.config["cull"]

    @cull.setter
    def cull(self, value: bool) -> None:
        self.config["cull"] = bool(value)

    @property
    def hops(self) -> int:
        """Graph hops that can change a prediction: ``mp_steps``, plus one for the pairwise decoder."""
        return self.network.hops

    @property
    def reach(self) -> float:
        """``hops * radius`` (data units): no particle farther than this from a particle changes its
        prediction (messages travel one radius per step)."""
        return self.hops * self.radius

    def num_parameters(self) -> int:
        """Number of trainable parameters."""
        return sum(p.numel() for p in self.parameters() if p.requires_grad)

    def _check_inputs(self, position_sequence: Tensor, particle_type: Tensor) -> None:
        shape = tuple(position_sequence.shape)
        if len(shape) != 3 or shape[1] != self.input_frames or shape[2] != self.dim:
            raise ValueError(
                "LearnedSimulator: position_sequence must be "
                f"[num_particles, {self.input_frames}, {self.dim}] (history + 1 frames, oldest first), "
                f"got {shape}"
            )
        if tuple(particle_type.shape) != shape[:1]:
            raise ValueError(
                f"LearnedSimulator: particle_type must be [num_particles] = [{shape[0]}], "
                f"got {tuple(particle_type.shape)}"
            )

    def build_graph(
        self, position_sequence: Tensor, particle_type: Tensor, batch: Tensor | None = None
    ) -> tuple[Tensor, Tensor, Tensor]:
        """Input graph of the network.

        Args:
            position_sequence: ``[N, history + 1, D]`` positions, oldest first.
            particle_type: ``[N]`` int64 type ids.
            batch: ``[N]`` graph id per particle, or ``None`` for one graph.

        Returns:
            node features ``[N, node_in]`` (velocities, walls, type), edge_index ``[2, E]`` (row 0 sender,
            row 1 receiver), edge features ``[E, D + 1]``.
        """
        self._check_inputs(position_sequence, particle_type)
        most_recent_position = position_sequence[:, -1]  # [N, D]
        walls = wall_features(most_recent_position, self.bounds, self.radius, self.wall_clip)
        edge_index = radius_graph(
            most_recent_position, self.radius, batch, self_loops=self.self_edges, method=self.neighbor_search
        )
        edge_attr = edge_features(most_recent_position, edge_index, self.radius)
        velocities = velocity_features(position_sequence, self.vel_mean, self.vel_std)
        if self.type_embedding is not None:
            material = self.type_embedding(particle_type)
        else:
            material = type_scalar_feature(particle_type, dtype=position_sequence.dtype)
        node_features = torch.cat([velocities, walls, material], dim=1)
        return node_features, edge_index, edge_attr

    def forward(
        self, position_sequence: Tensor, particle_type: Tensor, batch: Tensor | None = None
    ) -> Tensor:
        """Normalised acceleration ``[N, D]`` from positions ``[N, history + 1, D]`` (oldest first).

        With :attr:`cull`, the rows of static particles are 0 (not computed); see the module docstring.
        """
        return self._accelerations(
            position_sequence, particle_type, batch, particle_type != KINEMATIC_PARTICLE_ID
        )

    def _accelerations(
        self,
        position_sequence: Tensor,
        particle_type: Tensor,
        batch: Tensor | None,
        decode: Tensor,
        graph: tuple[Tensor, Tensor, Tensor] | None = None,
    ) -> Tensor:
        """Normalised acceleration ``[N, D]``; with :attr:`cull` only the rows of ``decode`` ``[N]`` (bool)
        are computed, the others are 0. ``graph``: :meth:`build_graph`'s output when already built."""
        output = self._network_output(position_sequence, particle_type, batch, decode, graph)
        if self.decoder == "node":
            return output
        wall, pairs = output.split(self.dim, dim=1)
        gate = wall_contact_gate(position_sequence[:, -1], self.bounds, self.radius)
        acceleration = self.free_fall + pairs + gate * wall
        if self.cull:  # rows that were not computed stay 0, as for "node" (no host sync to test decode.all())
            acceleration = acceleration * decode[:, None]
        return acceleration

    def _network_output(
        self,
        position_sequence: Tensor,
        particle_type: Tensor,
        batch: Tensor | None,
        decode: Tensor,
        graph: tuple[Tensor, Tensor, Tensor] | None,
    ) -> Tensor:
        """The network's output ``[N, D]`` (node decoder) or ``[N, 2 D]`` (pairwise: wall force, pair forces),
        culled as :meth:`_accelerations` says."""
        if graph is not None:
            return self.network(*graph, decode=decode if self.cull and not bool(decode.all()) else None)
        # Under CPU bf16 autocast the full graph, padded to fixed sizes, beats culling's ever-changing
        # prefixes (gnsx.model.padding); the decoded rows are the same either way.
        if not self.cull or needs_padding(position_sequence) or bool(decode.all()):
            node_features, edge_index, edge_attr = self.build_graph(position_sequence, particle_type, batch)
            return self.network(node_features, edge_index, edge_attr)
        self._check_inputs(position_sequence, particle_type)
        # Particles farther than the reach from every decoded one never enter the graph: the neighbour
        # search, the features and the hop sets then only see the neighbourhood of the decoded particles.
        keep = particles_in_reach(position_sequence[:, -1], decode, self.reach, batch)
        if bool(keep.all()):
            node_features, edge_index, edge_attr = self.build_graph(position_sequence, particle_type, batch)
            return self.network(node_features, edge_index, edge_attr, decode=decode)
        index = torch.nonzero(keep).squeeze(1)
        node_features, edge_index, edge_attr = self.build_graph(
            position_sequence.index_select(0, index),
            particle_type.index_select(0, index),
            None if batch is None else batch.index_select(0, index),
        )
        kept = self.network(node_features, edge_index, edge_attr, decode=decode.index_select(0, index))
        return kept.new_zeros(position_sequence.shape[0], kept.shape[1]).index_copy(0, index, kept)

    def integrate(self, normalized_acceleration: Tensor, position_sequence: Tensor) -> Tensor:
        """De-normalise (eq. 4) and step semi-implicit Euler with dt = 1 (eq. 5).

        Args:
            normalized_acceleration: ``[N, D]``.
            position_sequence: ``[N, >= 2, D]`` positions, oldest first.

        Returns:
            ``[N, D]`` next positions ``p + (v + a)`` with ``v = p[-1] - p[-2]`` (for whichever rows are
            given: :meth:`predict_positions` gives the moving particles only).
        """
        acceleration = normalized_acceleration * self.acc_std + self.acc_mean
        most_recent_position = position_sequence[:, -1]
        velocity = most_recent_position - position_sequence[:, -2]
        return most_recent_position + (velocity + acceleration)

    def predict_positions(
        self,
        position_sequence: Tensor,
        particle_type: Tensor,
        batch: Tensor | None = None,
        held: Tensor | None = None,
        graph: tuple[Tensor, Tensor, Tensor] | None = None,
    ) -> Tensor:
        """Next positions ``[N, D]``; static (kinematic) particles keep their most recent position. Only the
        others are decoded (with :attr:`cull`) and integrated.

        Args:
            position_sequence, particle_type, batch: as :meth:`forward`.
            held: ``[N]`` bool, dynamic particles to keep at their most recent position like static ones (not
                decoded); ``None``: none. The layer above's approximate freezing sets it
                (:class:`gnsx.rules.freezing.Freezing`).
            graph: :meth:`build_graph`'s output for these inputs when the caller has built it already.
        """
        moving = particle_type != KINEMATIC_PARTICLE_ID  # [N]
        if held is not None:
            moving = moving & ~held
        acceleration = self._accelerations(position_sequence, particle_type, batch, moving, graph)
        index = torch.nonzero(moving).squeeze(1)
        moved = self.integrate(acceleration.index_select(0, index), position_sequence.index_select(0, index))
        return position_sequence[:, -1].index_copy(0, index, moved)

    def normalized_target(self, next_position: Tensor, position_sequence: Tensor) -> Tensor:
        """Normalised acceleration ``[N, D]`` that moves ``position_sequence`` to ``next_position``.

        ``(p[k+1] - 2 p[k] + p[k-1] - acc_mean) / acc_std``, computed as a difference of velocities: a
        difference of two nearby float32 positions is exact (Sterbenz), whereas ``p[k+1] - 2 p[k]`` rounds
        at the scale of the positions (~3e-8 at 0.5, against accelerations of ~1e-4).
        """
        most_recent_position = position_sequence[:, -1]
        previous_velocity = most_recent_position - position_sequence[:, -2]
        next_velocity = next_position - most_recent_position
        acceleration = next_velocity - previous_velocity
        return (acceleration - self.acc_mean) / self.acc_std
