"""Encode-process-decode graph network (Battaglia et al. 2018; Sanchez-Gonzalez et al. 2020, GNS).

Paper equations (2)-(3), receiver i, sender j, sum over the senders of i:

    m_ij = phi_e([e_ij, v_i, v_j])          e_ij <- m_ij          (or e_ij + m_ij, DeepMind's GNS)
    v_i  <- v_i + phi_v([sum_j m_ij, v_i])

This module holds the one implementation that trains and rolls out (the fast path); a plain transcription of
the equations above lives in ``tests/reference_gns.py`` and the tests prove the two agree, forward and
backward, for both model configs. What makes it fast (CPU profile of a training step, 2 x ~500 particles,
~12k edges; numbers in the README's "Decisions"):

- **No per-edge concatenation.** phi_e's first layer is linear, so on ``[e_ij, v_i, v_j]`` it splits as
  ``W_e e_ij + (W_r v_i + b) + W_s v_j``: the node terms are projected once per node (N x H instead of
  E x H work) and gathered and summed per edge in one pass (:func:`gnsx.model.edge_ops.gather_sum`); the
  edge term is accumulated in place with ``addmm_``. phi_v's first layer splits the same way over
  ``[sum_j m_ij, v_i]``. The weights stay one ``Linear(3L, H)`` / ``Linear(2L, H)``, so checkpoints of every
  earlier version load unchanged.
- **Sum aggregation as a segment sum** over receiver-sorted edges (the radius graph and the culling plan
  sort them; :func:`gnsx.model.edge_ops.segment_sum`, ``index_add_`` for edges in any other order): one
  sequential read, and its backward is an ``index_select``, where the generic scatter of PyG's
  ``MessagePassing`` broadcasts the index to ``[E, L]`` and backpropagates through ``gather`` (2.5 ms per
  step and layer in the profile, more than the layer's forward). ``torch.segment_reduce`` and a CSR sparse
  product were measured too and were 2-2.5x slower forward + backward on this CPU.
- No Python message-passing framework between the layers: one gather-sum and one segment sum per layer,
  nothing else per edge but the MLPs. ``docs/speed.md`` has the profile, the matmul floor and what did not
  pay (edge blocks, a hand-written LayerNorm); ``compile_blocks`` (``model.compile``) fuses the rest.

Exact culling (``forward(..., decode=mask)``, :mod:`gnsx.model.culling`) is an option of this same path, not
a second model: the nodes are renumbered by hop distance from the decoded ones, so each step updates a prefix
of the node rows from a prefix of the (still receiver-sorted) edges, ``InteractionNetwork(num_receivers=...)``
on slices.
"""

from __future__ import annotations

import torch
from torch import Tensor, nn

from gnsx.model import fused
from gnsx.model.culling import plan_culling
from gnsx.model.edge_ops import add_product_, gather_sum, receiver_offsets, segment_sum
from gnsx.model.padding import needs_padding, pad_graph


class MLP(nn.Sequential):
    """``hidden_layers`` x (Linear, ReLU), then Linear, then LayerNorm if ``layer_norm``.

    The simplified GNS uses ``hidden_layers=1`` (Linear-ReLU-Linear, "a 2-layer MLP with one activated
    layer"); DeepMind's GNS ``hidden_layers=2``.

    Shapes: ``[..., in_size] -> [..., out_size]``.
    """

    def __init__(self, in_size: int, hidden_size: int, out_size: int, hidden_layers: int, layer_norm: bool):
        if hidden_layers < 0:
            raise ValueError(f"MLP: hidden_layers must be >= 0, got {hidden_layers}")
        sizes = [in_size] + [hidden_size] * hidden_layers
        layers: list[nn.Module] = []
        for fan_in, fan_out in zip(sizes[:-1], sizes[1:]):
            # In place: a Linear's backward does not need its output; ReLU's backward uses its result.
            layers += [nn.Linear(fan_in, fan_out), nn.ReLU(inplace=True)]
        layers.append(nn.Linear(sizes[-1], out_size))
        if layer_norm:
            layers.append(nn.LayerNorm(out_size))
        super().__init__(*layers)

    def forward(self, rows: Tensor) -> Tensor:
        # Inference on the CPU: the whole MLP in row tiles, no pass over memory per layer (gnsx.model.fused).
        if fused.runs(rows) and fused.mlp_layers(self):
            return fused.mlp(self, [rows], [self.first.weight])
        return super().forward(rows)

    @property
    def first(self) -> nn.Linear:
        """The first Linear layer (split by :class:`InteractionNetwork`)."""
        return self[0]

    def after_first(self, hidden: Tensor) -> Tensor:
        """Everything after the first Linear: ``[..., first.out_features] -> [..., out_size]``."""
        for layer in list(self)[1:]:
            hidden = layer(hidden)
        return hidden


class InteractionNetwork(nn.Module):
    """One message-passing step with its own weights; sum aggregation over incoming edges.

    Args:
        latent_size: L, size of node and edge latents.
        mlp_hidden_size: H, hidden width of phi_e and phi_v.
        mlp_hidden_layers: hidden layers of phi_e and phi_v (see :class:`MLP`).
        edge_residual: ``e <- e + m`` (DeepMind's GNS) instead of ``e <- m`` (the simplified model).
        layer_norm: LayerNorm at the end of phi_e and phi_v.

    Shapes:
        forward(x ``[N, L]``, edge_index ``[2, E]`` (row 0 sender j, row 1 receiver i),
        edge_attr ``[E, L]``) -> (x' ``[N, L]``, edge_attr' ``[E, L]``). With ``num_receivers=R`` (culling:
        every receiver index is below R) only the first R nodes are updated and x' is ``[R, L]``.

    The parameter names (``edge_mlp.*``, ``node_mlp.*``) and shapes are those of every earlier gnsx version.
    """

    def __init__(
        self,
        latent_size: int,
        mlp_hidden_size: int,
        mlp_hidden_layers: int,
        edge_residual: bool = False,
        layer_norm: bool = True,
    ):
        super().__init__()
        self.latent_size = latent_size
        self.edge_residual = edge_residual
        # phi_e input order [e_ij, v_i (receiver), v_j (sender)], as graph_nets' EdgeBlock.
        self.edge_mlp = MLP(3 * latent_size, mlp_hidden_size, latent_size, mlp_hidden_layers, layer_norm)
        # phi_v input order [sum_j m_ij, v_i], as graph_nets' NodeBlock.
        self.node_mlp = MLP(2 * latent_size, mlp_hidden_size, latent_size, mlp_hidden_layers, layer_norm)

    def forward(
        self,
        x: Tensor,
        edge_index: Tensor,
        edge_attr: Tensor,
        num_receivers: int | None = None,
        offsets: Tensor | None = None,
    ) -> tuple[Tensor, Tensor]:
        senders, receivers = edge_index[0], edge_index[1]
        latent = self.latent_size
        # Culling (gnsx.model.culling): only the first num_receivers nodes are updated; every receiver is
        # below it, senders may be any row. Slices are views, so the full graph pays nothing for this.
        receiver_x = x if num_receivers is None else x[:num_receivers]  # [R, L]
        if offsets is None:  # EncodeProcessDecode computes them once for all its steps
            offsets = receiver_offsets(receivers, receiver_x.shape[0])
        first = self.edge_mlp.first
        weight_edge, weight_receiver, weight_sender = first.weight.split(latent, dim=1)  # [H, L] each
        node_mlp = self.node_mlp
        weight_aggregated, weight_node = node_mlp.first.weight.split(latent, dim=1)
        if fused.edge_step_runs(self.edge_mlp, offsets, x, edge_attr) and fused.mlp_layers(node_mlp):
            # Inference on the CPU: phi_e, the sum and the edge update in L2-sized edge tiles, phi_v in node
            # tiles (gnsx.model.fused); same arithmetic, no pass over memory per layer. Both node terms of
            # phi_e's first layer in one [N, 2H] product (the bias only on the receiver half).
            hidden_size = first.out_features
            node_terms = torch.addmm(
                torch.cat([first.bias, first.bias.new_zeros(hidden_size)]),
                x,
                torch.cat([weight_receiver, weight_sender]).t(),
            )  # [N, 2H]
            edge_attr, aggregated = fused.edge_step(
                self.edge_mlp, node_terms[: receiver_x.shape[0], :hidden_size], node_terms[:, hidden_size:],
                edge_attr, senders, receivers, offsets, self.edge_residual,
            )  # fmt: skip
            x = fused.mlp(node_mlp, [aggregated, receiver_x], [weight_aggregated, weight_node], receiver_x)
            return x, edge_attr
        # phi_e's first layer, node parts once per node; the bias joins the R x H receiver term rather than
        # being broadcast over the E edges.
        receiver_term = torch.addmm(first.bias, receiver_x, weight_receiver.t())  # [R, H]
        sender_term = x @ weight_sender.t()  # [N, H]
        hidden = gather_sum(receiver_term, sender_term, receivers, senders, offsets)  # [E, H]
        # In place: one pass over the E x H output instead of a separate matmul result and add.
        add_product_(hidden, edge_attr, weight_edge.t())
        messages = self.edge_mlp.after_first(hidden)  # [E, L]
        # Sum over each receiver's incoming edges; backward is messages.grad = grad.index_select(receivers).
        aggregated = segment_sum(messages, receivers, offsets, receiver_x.shape[0])  # [R, L]
        node_hidden = add_product_(
            torch.addmm(node_mlp.first.bias, receiver_x, weight_node.t()), aggregated, weight_aggregated.t()
        )
        x = receiver_x + node_mlp.after_first(node_hidden)
        edge_attr = edge_attr + messages if self.edge_residual else messages
        return x, edge_attr

    def __repr__(self) -> str:
        return (
            f"{self.__class__.__name__}(latent_size={self.latent_size}, edge_residual={self.edge_residual})"
        )


class PairwiseDecoder(nn.Module):
    """Momentum-conserving decoder: antisymmetric pair forces summed per receiver.

    For the edge j -> i (sender j, receiver i) with processed node latents ``h_i``, ``h_j`` and the raw edge
    features ``x_ij = [(p_j - p_i) / R, |p_j - p_i| / R]``:

        f_ij = A([h_i, h_j, x_ij]) - A([h_j, h_i, x_ji])      x_ji = [-(p_j - p_i) / R, |p_j - p_i| / R]

    with ``A`` a Linear-ReLU-Linear MLP. Swapping i and j negates ``f``, so for a symmetric radius graph the
    pair forces of every pair cancel (Newton's third law) and the particles' summed output is 0 whatever the
    weights: a cluster touching no wall and no static particle keeps its centre of mass in free fall
    (Prantl et al. 2022 impose the same law with antisymmetric convolutions). Like phi_e's first layer,
    ``A``'s is split per node, so the two terms cost two gathers and no concatenation.

    Shapes: forward(h ``[N, L]`` (every sender's latent; receivers are the first R rows), edge_index
    ``[2, E]`` (receivers below R), x ``[E, D + 1]``, num_receivers R, offsets) -> ``[R, D]``.
    """

    def __init__(self, latent_size: int, edge_in: int, hidden_size: int, out_size: int):
        super().__init__()
        self.latent_size = latent_size
        self.first = nn.Linear(2 * latent_size + edge_in, hidden_size)
        self.second = nn.Linear(hidden_size, out_size, bias=False)  # a bias would cancel in the difference
        # x_ji from x_ij: the displacement changes sign, the distance does not.
        self.register_buffer("swap_sign", torch.tensor([-1.0] * (edge_in - 1) + [1.0]), persistent=False)

    def forward(
        self, h: Tensor, edge_index: Tensor, x: Tensor, num_receivers: int, offsets: Tensor | None
    ) -> Tensor:
        senders, receivers = edge_index[0], edge_index[1]
        latent = self.latent_size
        weight_first, weight_second, weight_edge = self.first.weight.split([latent, latent, x.shape[1]], 1)
        first_term = torch.addmm(self.first.bias, h, weight_first.t())  # [N, H]: h in A's first slot
        second_term = h @ weight_second.t()  # [N, H]: h in A's second slot
        forward_hidden = gather_sum(first_term[:num_receivers], second_term, receivers, senders, offsets)
        backward_hidden = gather_sum(second_term[:num_receivers], first_term, receivers, senders, offsets)
        add_product_(forward_hidden, x, weight_edge.t())  # in place, as phi_e's edge term
        # x_ji W^T = (x_ij * swap_sign) W^T = x_ij (W * swap_sign)^T: flip W's columns, no [E, D + 1] copy.
        add_product_(backward_hidden, x, (weight_edge * self.swap_sign).t())
        # A's second layer is linear: A(ij) - A(ji) = (relu(ij) - relu(ji)) W, one [E, D] product for both.
        forces = (torch.relu_(forward_hidden) - torch.relu_(backward_hidden)) @ self.second.weight.t()
        return segment_sum(forces, receivers, offsets, num_receivers)


DECODERS = ("node", "pairwise")


class EncodeProcessDecode(nn.Module):
    """Encoder MLPs -> ``mp_steps`` unshared :class:`InteractionNetwork` steps -> decoder MLP.

    Args:
        node_in: size of the input node features.
        edge_in: size of the input edge features.
        latent_size: L, size of node and edge latents (64 simplified, 128 GNS).
        mp_steps: M, number of message-passing steps (5 simplified, 10 GNS).
        mlp_hidden_size: hidden width of every MLP (64 simplified, 128 GNS).
        mlp_hidden_layers: hidden layers of every MLP (1 simplified, 2 GNS).
        out_size: size of the per-node output (dim: the normalised acceleration).
        edge_residual: residual edge update (GNS) or plain replacement (simplified).
        layer_norm: LayerNorm after every MLP except the decoder.
        decoder: ``"node"`` (the GNS decoder MLP per node) or ``"pairwise"``: the node decoder plus a
            :class:`PairwiseDecoder` on the edges into each node, which reads the latents of the senders
            too, so an output depends on the nodes within ``mp_steps + 1`` hops (:attr:`hops`).

    Shapes:
        forward(x ``[N, node_in]``, edge_index ``[2, E]``, edge_attr ``[E, edge_in]``, decode ``[N]`` bool or
        None) -> ``[N, out_size]`` (node decoder) or ``[N, 2 * out_size]`` (pairwise: ``[node decoder, sum
        of pair forces]``). With ``decode`` (exact culling, :mod:`gnsx.model.culling`) only the rows of
        ``decode`` are computed, from the nodes within :attr:`hops` hops of them; the others are 0.
    """

    def __init__(
        self,
        node_in: int,
        edge_in: int,
        latent_size: int,
        mp_steps: int,
        mlp_hidden_size: int,
        mlp_hidden_layers: int,
        out_size: int,
        edge_residual: bool,
        layer_norm: bool,
        decoder: str = "node",
    ):
        super().__init__()
        if decoder not in DECODERS:
            raise ValueError(f"EncodeProcessDecode: decoder must be one of {DECODERS}, got {decoder!r}")
        self.node_encoder = MLP(node_in, mlp_hidden_size, latent_size, mlp_hidden_layers, layer_norm)
        self.edge_encoder = MLP(edge_in, mlp_hidden_size, latent_size, mlp_hidden_layers, layer_norm)
        self.processor = nn.ModuleList(
            InteractionNetwork(latent_size, mlp_hidden_size, mlp_hidden_layers, edge_residual, layer_norm)
            for _ in range(mp_steps)
        )
        self.decoder = MLP(latent_size, mlp_hidden_size, out_size, mlp_hidden_layers, layer_norm=False)
        self.pair_decoder = None
        if decoder == "pairwise":
            self.pair_decoder = PairwiseDecoder(latent_size, edge_in, mlp_hidden_size, out_size)
        #: Hops from which a node's output can be reached: one per step, one more for the pair decoder.
        self.hops = mp_steps + (self.pair_decoder is not None)

    def compile_blocks(self) -> None:
        """``torch.compile`` the encoders, every message-passing step and the decoder, in place.

        Per block rather than the whole forward: the culling plan's Python ints and data-dependent sizes stay
        outside the compiled code, and the steps share one compiled graph (same code, parameters as inputs).
        ``dynamic=True`` because the node and edge counts change every frame; without it every new size
        recompiles. Parameters and their names are unchanged (checkpoints load either way).
        """
        blocks = (self.node_encoder, self.edge_encoder, *self.processor, self.decoder, self.pair_decoder)
        for block in blocks:
            if block is not None:
                block.compile(dynamic=True)

    def forward(
        self, x: Tensor, edge_index: Tensor, edge_attr: Tensor, decode: Tensor | None = None
    ) -> Tensor:
        if decode is not None:
            return self._culled(x, edge_index, edge_attr, decode)
        num_nodes = x.shape[0]
        if needs_padding(x):  # bf16 on the CPU: a few fixed shapes (gnsx.model.padding)
            x, edge_index, edge_attr = pad_graph(x, edge_index, edge_attr)
        node_latent = self.node_encoder(x)
        edge_latent = self.edge_encoder(edge_attr)
        offsets = receiver_offsets(edge_index[1], x.shape[0])
        for step in self.processor:
            node_latent, edge_latent = step(node_latent, edge_index, edge_latent, offsets=offsets)
        decoded = self.decoder(node_latent)
        if self.pair_decoder is not None:
            pairs = self.pair_decoder(node_latent, edge_index, edge_attr, x.shape[0], offsets)
            decoded = torch.cat([decoded, pairs], dim=1)
        return decoded[:num_nodes]

    def _culled(self, x: Tensor, edge_index: Tensor, edge_attr: Tensor, decode: Tensor) -> Tensor:
        """The same outputs for the nodes of ``decode``, computing only what they depend on (a shrinking
        frontier, :mod:`gnsx.model.culling`); the other rows are 0."""
        plan = plan_culling(edge_index, decode, self.hops)
        node_latent = self.node_encoder(x.index_select(0, plan.nodes))  # [n_hops, L]
        edge_attr = edge_attr.index_select(0, plan.edges)  # [e_{hops-1}, edge_in]
        edge_latent = self.edge_encoder(edge_attr)
        # Row pointer of the first step's receivers; the later steps' edges are prefixes of it.
        offsets = receiver_offsets(plan.edge_index[1], plan.node_counts[-2] if self.hops else 0)
        # With the pair decoder the last step still updates the decoded nodes' neighbours (its senders).
        last = self.hops - len(self.processor)
        for step, hops_left in zip(self.processor, range(self.hops - 1, last - 1, -1)):
            # Step k updates the nodes within M - k hops, from the edges into them (prefixes of the plan).
            num_edges = plan.edge_counts[hops_left]
            node_latent, edge_latent = step(
                node_latent,
                plan.edge_index[:, :num_edges],
                edge_latent[:num_edges],
                num_receivers=plan.node_counts[hops_left],
                offsets=offsets,
            )
        decoded = self.decoder(node_latent[: plan.num_decoded])  # [n_0, out]
        if self.pair_decoder is not None:
            num_edges = plan.edge_counts[0]
            pairs = self.pair_decoder(
                node_latent,
                plan.edge_index[:, :num_edges],
                edge_attr[:num_edges],
                plan.num_decoded,
                offsets,
            )
            decoded = torch.cat([decoded, pairs], dim=1)
        out = decoded.new_zeros(x.shape[0], decoded.shape[1])
        return out.index_copy(0, plan.nodes[: plan.num_decoded], decoded)
