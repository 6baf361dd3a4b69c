"""Average the weights of several checkpoints of one run (stochastic weight averaging after the fact).

    .venv/bin/python scripts/average_checkpoints.py outputs/swa/avg40_100.ckpt \\
        outputs/pretrain/small/checkpoints/permanent/step000{4,5,6,7,8,9}0000.ckpt \\
        outputs/pretrain/small/checkpoints/permanent/step00100000.ckpt

Writes OUT: the last checkpoint with every floating-point tensor of its ``state_dict`` replaced by the mean
over the inputs (in float64, stored in the original dtype), and without optimizer, scheduler and loop state,
so it evaluates like any checkpoint but cannot be resumed. README "Decisions" has what it measured.
"""

from __future__ import annotations

import sys

import torch


def main(out: str, paths: list[str]) -> None:
    if not paths:
        raise SystemExit("usage: average_checkpoints.py OUT CKPT [CKPT ...]")
    states = [torch.load(path, map_location="cpu", weights_only=False) for path in paths]
    averaged = states[-1]
    averaged["state_dict"] = {
        key: (sum(s["state_dict"][key].double() for s in states) / len(states)).to(value.dtype)
        if value.is_floating_point()
        else value
        for key, value in averaged["state_dict"].items()
    }
    for key in ("optimizer_states", "lr_schedulers", "callbacks", "loops"):
        averaged.pop(key, None)
    torch.save(averaged, out)
    print(f"wrote {out}: mean of {len(states)} checkpoints")


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2:])
