"""A diagnosis from the shell, end to end, beside ``import torch``: the wall time a user waits.

    python -m experiments.bench.bench_shell [--repeats 5] [--profile FILE] [--baseline DIR]

Cases, each a fresh process with the report written (figures included), the commands interleaved
so that a change in the machine's load hits them alike:

- ``pendulum``: a pendulum with quadratic air drag missing from its starting model, 4,000 samples,
  the angle measured with 1 % noise (the rate and acceleration estimated), a torque input; the
  record is a CSV written by this script (its own generator: scipy's ``solve_ivp``, not the
  package's systems).
- ``README example``: ``msam diagnose configs/msd_coulomb.yaml``, the bundled system simulated at
  start (warm: its cached simulation reused; cold: an empty cache folder each run).

Printed: the median wall time of each and its ratio to ``python -c "import torch"`` of the same
run, the same for the CPU time its process used (less sensitive to other jobs on the machine),
and the diagnosis's own time in-process (``GapReport.seconds``, the median of ``--repeats`` runs in
this process after one warm-up). ``--profile FILE`` also writes a cProfile of one
pendulum diagnosis from the shell (read it with ``python -m pstats FILE``). ``--baseline DIR`` times
the warm-cache commands a second time with the package of another checkout (``DIR``, a worktree of
main, say) on the path, interleaved with the rest, each marked "(baseline)".
"""
from __future__ import annotations

import argparse
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
PENDULUM = """\
# A pendulum whose air drag (quadratic in the rate) is missing: theta_ddot = -(g/l) sin(theta) - c theta_dot + u/(m l^2)
model:
  states: [theta, theta_dot]
  inputs: [u]
  parameters: {g_l: 9.81, c: 0.1, J: 1.0}
  quantities: {theta: angle, theta_dot: angular_velocity, u: torque}
  equations:
    - target: theta_ddot
      components:
        - {term: sin(theta), theta: -g_l}
        - {term: theta_dot, theta: -c}
        - {term: u, theta: 1/J, adjustable: false}
      adjustments: [abs(theta), abs(theta_dot)]
data:
  file: pendulum.csv
  time: t
  columns: {theta: theta, u: u}
"""


def pendulum_record(folder: Path, samples: int = 4000, noise: float = 0.01, seed: int = 0) -> Path:
    """Write ``pendulum.csv`` and ``pendulum.yaml`` into ``folder``; return the config's path."""
    from scipy.integrate import solve_ivp

    t = np.linspace(0.0, 40.0, samples)
    freqs = np.array([0.2, 0.35, 0.55, 0.8, 1.1, 1.5])
    phases = -np.pi * np.arange(1, 7) * np.arange(0, 6) / 6
    u = lambda tt: 1.5 * np.sin(np.multiply.outer(tt, 2 * np.pi * freqs) + phases).sum(-1) / np.sqrt(3)
    rhs = lambda tt, s: [s[1], -9.81 * np.sin(s[0]) - 0.1 * s[1] - 0.5 * s[1] * abs(s[1]) + u(tt)]
    theta = solve_ivp(rhs, (0.0, 40.0), [0.0, 0.0], t_eval=t, rtol=1e-10, atol=1e-10).y[0]
    rng = np.random.default_rng(seed)
    measured = theta + noise * theta.std() * rng.standard_normal(samples)
    np.savetxt(folder / "pendulum.csv", np.column_stack([t, measured, u(t)]), delimiter=",",
               header="t,theta,u", comments="", fmt="%.10g")
    (folder / "pendulum.yaml").write_text(PENDULUM)
    return folder / "pendulum.yaml"


def wall_time(command: list[str], env: dict, cwd: Path = ROOT) -> tuple[float, float]:
    """The wall time of ``command`` and the CPU time (user and system) its process used."""
    start, cpu = time.perf_counter(), _children_cpu()
    subprocess.run(command, cwd=cwd, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env)
    return time.perf_counter() - start, _children_cpu() - cpu


def _children_cpu() -> float:
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def in_process(config: Path, repeats: int) -> tuple[float, str]:
    from msam_torch import diagnose

    diagnose(config)
    reports = [diagnose(config) for _ in range(repeats)]
    return statistics.median(r.seconds for r in reports), reports[0].verdict


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeats", type=int, default=5, help="runs of each command (median printed)")
    parser.add_argument("--profile", type=Path, help="write a cProfile of one pendulum diagnosis here")
    parser.add_argument("--baseline", type=Path, help="a checkout whose msam_torch is timed beside this one")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as scratch:
        folder = Path(scratch)
        pendulum = pendulum_record(folder)
        env = {**os.environ, "PYTHONPATH": str(ROOT), "MSAM_CACHE_DIR": str(folder / "cache")}
        msam = [sys.executable, "-m", "msam_torch", "diagnose"]
        timed = {
            'python -c "import torch"': ([sys.executable, "-c", "import torch"], env),
            "pendulum, 4,000 samples (CSV)": (msam + [str(pendulum), "--out", str(folder / "p")], env),
            "README example (warm cache)": (msam + ["configs/msd_coulomb.yaml", "--out", str(folder / "w")], env),
        }
        if args.baseline:  # run in its folder: python -m puts the working folder first on the path
            base = args.baseline.resolve()
            other = {**env, "PYTHONPATH": str(base)}
            timed["pendulum, 4,000 samples (CSV) (baseline)"] = (msam + [str(pendulum), "--out", str(folder / "pb")],
                                                                 other, base)
            timed["README example (warm cache) (baseline)"] = (
                msam + ["configs/msd_coulomb.yaml", "--out", str(folder / "wb")], other, base)
        cold = lambda i: {**env, "MSAM_CACHE_DIR": str(folder / f"cold{i}")}
        times: dict[str, list[tuple[float, float]]] = {name: [] for name in [*timed, "README example (cold cache)"]}
        for command, *where in timed.values():  # one untimed run each: file-system caches warm
            wall_time(command, *where)
        for i in range(args.repeats):
            for name, (command, *where) in timed.items():
                times[name].append(wall_time(command, *where))
            times["README example (cold cache)"].append(wall_time(timed["README example (warm cache)"][0], cold(i)))
        if args.profile:
            subprocess.run([sys.executable, "-m", "cProfile", "-o", str(args.profile), *msam[1:], str(pendulum),
                            "--out", str(folder / "profiled")], cwd=ROOT, check=True, stdout=subprocess.DEVNULL,
                           env=env)
        os.environ["MSAM_CACHE_DIR"] = env["MSAM_CACHE_DIR"]
        seconds, verdict = in_process(pendulum, args.repeats)
    median = lambda name, k: statistics.median(run[k] for run in times[name])
    torch_wall, torch_cpu = (median('python -c "import torch"', k) for k in (0, 1))
    print(f"median wall time of {args.repeats} runs each, {os.cpu_count()} CPUs, load {os.getloadavg()[0]:.1f}")
    print("| command | median s | min s | vs import torch | CPU s | CPU vs import torch |\n|---|---|---|---|---|---|")
    for name, runs in times.items():
        print(f"| {name} | {median(name, 0):.2f} | {min(run[0] for run in runs):.2f} | {median(name, 0) / torch_wall:.2f}x "
              f"| {median(name, 1):.2f} | {median(name, 1) / torch_cpu:.2f}x |")
    print(f"pendulum diagnosis in-process (GapReport.seconds, median of {args.repeats}): {seconds:.3f} s; "
          f"verdict: {verdict}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
