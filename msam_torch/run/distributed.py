"""The round robin sharded over processes with ``torch.distributed`` (the paper's section 6:
candidates are independent, so Stage 1 runs in parallel in ``Q^n / p``).

Each rank adapts a contiguous slice of the candidates; the best fitness, exponents and divergence
flags of every candidate are all-gathered, so every rank picks the same winner and refines it
exactly as a single process would. Backend: gloo on CPU, nccl on CUDA. Run under torchrun:

    torchrun --nproc_per_node=2 -m msam_torch.run.distributed configs/sode3.yaml --out result.json

Without an initialised process group (plain ``python``) it runs as one process.
"""
from __future__ import annotations

import argparse
import os
import sys

import torch
import torch.distributed as dist

from msam_torch.config.schema import load_config
from msam_torch.engine.trainer import Trainer
from msam_torch.engine.values import State
from msam_torch.errors import MSAMError
from msam_torch.run.adapt import adapt
from msam_torch.run.plan import Plan


class ShardedTrainer(Trainer):
    """A :class:`Trainer` whose round robin is split over the ranks of the default process group."""

    def round_robin(self, data, theta, theta_fixed, start, choices, offset: int = 0):
        world = dist.get_world_size() if dist.is_available() and dist.is_initialized() else 1
        if world == 1 or len(choices) < world:
            return super().round_robin(data, theta, theta_fixed, start, choices, offset)
        rank = dist.get_rank()
        bounds = [len(choices) * r // world for r in range(world + 1)]
        width = max(b - a for a, b in zip(bounds, bounds[1:]))
        mine = choices[bounds[rank]: bounds[rank + 1]]
        fitness, state, diverged = super().round_robin(data, theta, theta_fixed, start, mine, offset + bounds[rank])
        fields = [fitness.unsqueeze(-1), diverged.to(fitness.dtype).unsqueeze(-1), state.gamma, state.theta, state.theta_fixed]
        if state.initial is not None:
            fields.append(state.initial)
        sizes = [f.shape[-1] for f in fields]
        packed = torch.cat(fields, -1)
        local = packed.new_zeros((packed.shape[0], width, packed.shape[-1]))
        local[:, : len(mine)] = packed
        gathered = [torch.empty_like(local) for _ in range(world)]
        dist.all_gather(gathered, local)
        joined = torch.cat([g[:, : b - a] for g, a, b in zip(gathered, bounds, bounds[1:])], 1)
        parts = torch.split(joined, sizes, -1)
        flag = parts[1][..., 0] > 0
        ranking = State(parts[2], parts[3], parts[4], flag, parts[5] if len(parts) > 5 else None)
        return parts[0][..., 0], ranking, flag


def sharded_trainer(plan: Plan) -> ShardedTrainer:
    a = plan.config.adaptation
    return ShardedTrainer(plan.options, a.round_robin_steps, a.refinement_steps, a.chunk_size, plan.evaluator)


def init_process_group(device: str) -> bool:
    """Join the torchrun process group (gloo on CPU, nccl on CUDA); False when not under torchrun."""
    if "WORLD_SIZE" not in os.environ or dist.is_initialized():
        return dist.is_initialized()
    backend = "nccl" if device.startswith("cuda") else "gloo"
    if backend == "nccl":
        torch.cuda.set_device(int(os.environ.get("LOCAL_RANK", 0)))
    dist.init_process_group(backend)
    return True


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="msam_torch.run.distributed", description=__doc__.split("\n\n")[0])
    parser.add_argument("config")
    parser.add_argument("overrides", nargs="*")
    parser.add_argument("--out", required=True, help="result.json written by rank 0")
    args = parser.parse_args(argv)
    try:
        config = load_config(args.config, args.overrides)
        if config.adaptation.device.startswith("cuda") and "LOCAL_RANK" in os.environ:
            config = load_config(args.config, args.overrides + [f"adaptation.device=cuda:{os.environ['LOCAL_RANK']}"])
        joined = init_process_group(config.adaptation.device)
        result = adapt(config, trainer_factory=sharded_trainer, base_dir=os.path.dirname(args.config) or ".")
    except MSAMError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    if not joined or dist.get_rank() == 0:
        result.save(args.out)
        print(result)
    if joined:
        dist.barrier()
        dist.destroy_process_group()
    return 0


if __name__ == "__main__":
    sys.exit(main())
