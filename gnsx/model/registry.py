"""The model registry: the named GNS configurations as :class:`LearnedSimulator` arguments, and untrained
instances of them at WaterRamps' facts (what the speed benchmarks time; conf/model/*.yaml are the same
configurations for training)."""

from __future__ import annotations

from gnsx.data.waterramps import WATERRAMPS
from gnsx.model.simulator import LearnedSimulator

#: Keys of a ``conf/model/*.yaml`` that are not :class:`LearnedSimulator` arguments: the config's name, the
#: training noise and its decay, DeepMind's noise-widened normalisation switch, and the radius (a data fact
#: that ``model.radius`` may override, or ``model.radius_scale`` scale).
MODEL_CONFIG_EXTRAS = ("name", "noise_std", "noise_decay", "widen_stats_by_noise", "radius", "radius_scale")

#: The two models of the paper's comparison and gnsx's default (``simplified_pairwise``: the simplified model
#: with the momentum-conserving decoder and the wall feature clipped at 10 R), as LearnedSimulator arguments
#: (conf/model/*.yaml).
MODELS = {
    "simplified": {},
    "simplified_pairwise": {"wall_clip": (0.0, 10.0), "decoder": "pairwise"},
    "original": {
        "latent_size": 128,
        "mp_steps": 10,
        "mlp_hidden_size": 128,
        "mlp_hidden_layers": 2,
        "history": 5,
        "type_encoding": "embedding",
        "wall_clip": (-1.0, 1.0),
        "edge_residual": True,
        "self_edges": True,
    },
}
#: What the timing modes run without ``--models``: the paper's pair and gnsx's default between them.
DEFAULT_MODELS = ("simplified", "simplified_pairwise", "original")


def build_model(name: str, radius: float = WATERRAMPS["radius"], **overrides) -> LearnedSimulator:
    """An untrained simplified or original GNS with WaterRamps' bounds and statistics (speed needs no
    training)."""
    if name not in MODELS:
        raise KeyError(f"unknown model {name!r}; known: {sorted(MODELS)}")
    facts = {k: WATERRAMPS[k] for k in ("bounds", "vel_mean", "vel_std", "acc_mean", "acc_std")}
    return LearnedSimulator(dim=2, radius=radius, **(facts | MODELS[name] | overrides)).eval()
