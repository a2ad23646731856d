"""Engine benchmark, printed in one run:

1. round-robin step time (one Eq. 15-20 step + evaluation of every candidate) for 4, 27, 729 and
   4096 candidates at N = 1e3, 1e4, 1e5 samples, batched (cache-sized chunks of candidates, run one
   after another as the Trainer does; the step time is the sum over chunks of the r-th repeat) vs the sequential reference path (one Candidate module at a time, torch.func
   sensitivities; measured on a few candidates and scaled to all), their ratio, and peak memory;
2. 4096 candidates at N = 1e4 for 15 round-robin steps (wall time, peak memory), in one process
   and sharded over ``--ranks`` processes (torch.distributed, as ``msam_torch.run.distributed``);
3. wall time of each table protocol (Tables 2-4, Figure 5; the batched tensor programs).

    python -m experiments.bench.bench_engine [--threads 1] [--ranks 2] [--repeats 7] [--skip-tables]

Each cell runs in its own process so that its peak resident memory (ru_maxrss, including the
~0.35 GB of the Python + torch runtime) is its own. Timings on a shared machine vary: every step
time is the median of ``--repeats`` repeats, and CPU time is printed beside wall time.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import os
import resource
import statistics
import subprocess
import sys
import time
from pathlib import Path

from msam_torch.config.to_spec import to_spec

ROOT = Path(__file__).resolve().parents[2]
CANDIDATES = {4: ("harmonic", None), 27: ("sode3", None), 729: ("wide", 3), 4096: ("wide", 4)}
SAMPLES = (1_000, 10_000, 100_000)
MAX_VALUES = 10**9  # cells with more (C x N x Q) values per step are skipped unless --all
FEW_REPEATS_ABOVE = 10**7  # larger cells: 3 repeats


def problem(candidates: int, samples: int):
    """EquationData, nominal theta (adjustable, fixed) and equation for a candidate count."""
    from msam_torch.config.schema import load_config
    from msam_torch.data.systems import SYSTEMS, measure
    from msam_torch.engine.candidates import EquationData

    name, functions = CANDIDATES[candidates]
    if name == "wide":  # six components of the third-order model's states, F = {x1, x2, x3[, |x1|]}
        terms = ["x1", "x2", "x3", "x1*x2", "x1*x3", "x2*x3"]
        raw = {"model": {"states": ["x1", "x2", "x3"], "parameters": {f"a{i}": -1.0 for i in range(6)},
                         "equations": [{"target": "x1_dot", "adjustments": ["x1", "x2", "x3", "abs(x1)"][:functions],
                                        "components": [{"term": t, "theta": f"a{i}"} for i, t in enumerate(terms)]}]},
               "data": {"system": "sode3"}}
        config = load_config(raw)
    else:
        config = load_config(ROOT / "configs" / f"{name}.yaml")
    spec = to_spec(config.model)
    equation = spec.equations[0]
    system = dataclasses.replace(SYSTEMS[config.data.system], samples=samples)
    data = EquationData.build(equation, measure(system))
    theta = spec.theta(equation)
    return data, theta[list(equation.adjustable)], theta[list(equation.fixed)], equation


def cell(candidates: int, samples: int, repeats: int, sequential: int) -> dict:
    """Median batched step time, scaled sequential step time, peak memory of one cell."""
    import torch

    from msam_torch.engine.candidates import Candidate, enumerate_choices
    from msam_torch.engine.reference import reference_fitness, reference_step
    from msam_torch.engine.step import evaluate, step
    from msam_torch.engine.values import State, StepOptions
    from msam_torch.run.trials import MAX_ELEMENTS, chunk_size

    data, theta, theta_fixed, _ = problem(candidates, samples)
    options = StepOptions()
    q = theta.shape[0]
    choices = enumerate_choices(data.log_f.shape[-1], q)
    size = chunk_size(1, samples, q, MAX_ELEMENTS)
    wall, cpu = [0.0] * repeats, [0.0] * repeats
    for first in range(0, len(choices), size):  # one chunk at a time, as the Trainer runs them
        selection = data.select(choices[first: first + size])
        c = selection.log_f.shape[1]
        state = State(torch.zeros(1, c, q, dtype=torch.float64), theta.expand(1, c, q),
                      theta_fixed.expand(1, c, theta_fixed.shape[0]), torch.zeros(1, c, dtype=torch.bool))
        current = evaluate(selection, state, options)
        for r in range(repeats + 1):  # the first step warms up (allocations, perturbation factors)
            t0, c0 = time.perf_counter(), time.process_time()
            state = step(selection, state, current, options, conditions=False).state
            current = evaluate(selection, state, options)
            if r:
                wall[r - 1] += time.perf_counter() - t0
                cpu[r - 1] += time.process_time() - c0
    measured = min(sequential, len(choices))
    seq = []
    for _ in range(max(1, min(3, repeats))):
        t0 = time.perf_counter()
        for k in range(measured):
            module = Candidate(choices[k], theta, theta_fixed)
            result = reference_step(module, data, options)
            reference_fitness(Candidate(choices[k], theta, theta_fixed, result.gamma), data, options)
        seq.append((time.perf_counter() - t0) * len(choices) / measured)
    batched, sequential_time = statistics.median(wall), statistics.median(seq)
    return {"candidates": candidates, "samples": samples, "batched_ms": 1e3 * batched, "batched_min_ms": 1e3 * min(wall),
            "batched_cpu_ms": 1e3 * statistics.median(cpu), "sequential_ms": 1e3 * sequential_time,
            "sequential_measured_on": measured, "ratio": sequential_time / batched, "chunk": size,
            "peak_rss_gb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20}


def long_run(candidates: int, samples: int, steps: int) -> dict:
    """Stage 1 of Algorithm 1 for ``steps`` steps: wall time, peak memory. Under torchrun the
    candidates are sharded over the ranks (:class:`msam_torch.run.distributed.ShardedTrainer`); the wall
    time is the slowest rank's, CPU time and peak memory the sum over ranks."""
    import torch
    import torch.distributed as dist

    from msam_torch.engine.candidates import enumerate_choices
    from msam_torch.engine.values import StepOptions
    from msam_torch.run.distributed import ShardedTrainer, init_process_group
    from msam_torch.run.trials import chunk_size

    joined = init_process_group("cpu")
    data, theta, theta_fixed, _ = problem(candidates, samples)
    q = theta.shape[0]
    trainer = ShardedTrainer(StepOptions(), steps, 0, chunk_size(1, samples, q))
    choices = enumerate_choices(data.log_f.shape[-1], q)
    if joined:
        dist.barrier()
    t0, c0 = time.perf_counter(), time.process_time()
    fitness, _, _ = trainer.round_robin(data, theta.unsqueeze(0), theta_fixed.unsqueeze(0),
                                        torch.zeros(q, dtype=torch.float64), choices)
    mine = [time.perf_counter() - t0, time.process_time() - c0, resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20]
    ranks = [mine]
    if joined:
        ranks = [None] * dist.get_world_size()
        dist.all_gather_object(ranks, mine)
        dist.destroy_process_group()
    return {"candidates": candidates, "samples": samples, "steps": steps, "ranks": len(ranks),
            "wall_s": max(r[0] for r in ranks), "cpu_s": sum(r[1] for r in ranks),
            "finite": int(torch.isfinite(fitness).sum()), "peak_rss_gb": sum(r[2] for r in ranks)}


def tables() -> list[dict]:
    """Wall time of each table protocol's tensor programs (no file output)."""
    from experiments.common import all_trials, load_experiment, model_config, model_path
    from msam_torch.run.trials import run_trials

    rows = []
    for name in ("table2_harmonic", "table2_vanderpol", "table3", "table4", "figure5"):
        path = ROOT / "experiments" / "paper" / f"{name}.yaml"
        experiment = load_experiment(path)
        settings = {k: {n: v for n, v in s.model_dump().items() if n != "truth" and v is not None}
                    for k, s in experiment.equations.items()}
        for variant in experiment.variants:
            config = model_config(experiment, path, variant)
            trials = all_trials(experiment)
            t0, c0 = time.perf_counter(), time.process_time()
            run_trials(config, trials, experiment.seed, model_path(experiment, path).parent, settings,
                       max_elements=experiment.max_elements)
            rows.append({"protocol": f"{name}/{variant}", "trials": len(trials), "wall_s": time.perf_counter() - t0,
                         "cpu_s": time.process_time() - c0})
    return rows


def child(args) -> None:
    import torch

    from msam_torch.engine.allocator import keep_freed_memory

    keep_freed_memory()  # as the command-line tool and the experiments run
    torch.set_num_threads(args.threads)
    if args.cell:
        out = cell(args.cell[0], args.cell[1], args.repeats, args.sequential)
    elif args.long:
        out = long_run(args.long[0], args.long[1], args.long[2])
    else:
        out = {"tables": tables(), "peak_rss_gb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20}
    if os.environ.get("RANK", "0") == "0":  # under torchrun: every rank holds the gathered figures
        print("RESULT " + json.dumps(out))


def spawn(args, *extra: str, ranks: int = 1) -> dict | None:
    launcher = ["-m", "torch.distributed.run", "--standalone", f"--nproc_per_node={ranks}"] if ranks > 1 else []
    command = [sys.executable, *launcher, __file__, "--threads", str(args.threads), "--repeats", str(args.repeats),
               "--sequential", str(args.sequential), *extra]
    env = {**os.environ, "PYTHONPATH": str(ROOT), "OMP_NUM_THREADS": str(args.threads)}
    done = subprocess.run(command, env=env, capture_output=True, text=True)
    for line in done.stdout.splitlines():
        if line.startswith("RESULT "):
            return json.loads(line[7:])
    print(f"  failed: {' '.join(extra)}: {done.stderr.strip().splitlines()[-1:] }")
    return None


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--threads", type=int, default=1, help="intra-op threads per process (1: fastest on a shared machine)")
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--sequential", type=int, default=4, help="candidates timed on the sequential path")
    parser.add_argument("--ranks", type=int, default=os.cpu_count(), help="processes for the sharded 4096-candidate run")
    parser.add_argument("--skip-tables", action="store_true")
    parser.add_argument("--all", action="store_true", help="also the cells above 1e9 values per step")
    parser.add_argument("--cell", type=int, nargs=2, help=argparse.SUPPRESS)
    parser.add_argument("--long", type=int, nargs=3, help=argparse.SUPPRESS)
    parser.add_argument("--tables-only", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.cell or args.long or args.tables_only:
        child(args)
        return 0
    print(f"msam-torch engine benchmark: {args.threads} threads, median of {args.repeats} steps, "
          f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} CPUs at start")
    print("\n1. round-robin step (step + evaluation of every candidate), float64, literal options")
    print(f"{'C':>5} {'N':>7} {'batched ms':>11} {'min ms':>8} {'cpu ms':>8} {'sequential ms':>14} {'ratio':>7} {'peak GB':>8}")
    for candidates in CANDIDATES:
        for samples in SAMPLES:
            q = 6 if candidates > 27 else (3 if candidates == 27 else 2)
            if candidates * samples * q > MAX_VALUES and not args.all:
                print(f"{candidates:>5} {samples:>7}  skipped: {candidates * samples * q:.1e} values per step (--all runs it)")
                continue
            repeats = args.repeats if candidates * samples * q <= FEW_REPEATS_ABOVE else 3
            r = spawn(args, "--cell", str(candidates), str(samples), "--repeats", str(repeats))
            if r:
                print(f"{candidates:>5} {samples:>7} {r['batched_ms']:>11.3f} {r['batched_min_ms']:>8.3f} "
                      f"{r['batched_cpu_ms']:>8.3f} {r['sequential_ms']:>14.1f} {r['ratio']:>7.1f} {r['peak_rss_gb']:>8.2f}"
                      f"   (sequential timed on {r['sequential_measured_on']}, chunk {r['chunk']})", flush=True)
    print("\n2. 4096 candidates, N = 10000, 15 round-robin steps (Trainer.round_robin; sharded over ranks "
          "by torch.distributed, gloo, one process per rank)")
    for ranks in sorted({1, args.ranks}):
        r = spawn(args, "--long", "4096", "10000", "15", ranks=ranks)
        if r:
            print(f"   {r['ranks']} rank(s) x {args.threads} thread(s): wall {r['wall_s']:.1f} s, cpu {r['cpu_s']:.1f} s, "
                  f"peak RSS {r['peak_rss_gb']:.2f} GB (all ranks), {r['finite']} candidates with finite fitness", flush=True)
    if not args.skip_tables:
        print("\n3. table protocols (batched tensor programs, no file output)")
        r = spawn(args, "--tables-only")
        if r:
            for row in r["tables"]:
                print(f"   {row['protocol']:<30} {row['trials']:>4} trials  wall {row['wall_s']:7.2f} s  cpu {row['cpu_s']:7.2f} s")
            for name in dict.fromkeys(row["protocol"].split("/")[0] for row in r["tables"]):
                rows = [row for row in r["tables"] if row["protocol"].startswith(name + "/")]
                if len(rows) > 1:
                    print(f"   {name + ' (all variants)':<30} {sum(x['trials'] for x in rows):>4} trials  "
                          f"wall {sum(x['wall_s'] for x in rows):7.2f} s  cpu {sum(x['cpu_s'] for x in rows):7.2f} s")
            print(f"   peak RSS {r['peak_rss_gb']:.2f} GB")
    print(f"\nload average {os.getloadavg()[0]:.1f} at the end (other processes share these CPUs)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
