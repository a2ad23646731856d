"""Records of the withheld-effect systems (:data:`~msam_torch.data.systems.WITHHELD`) at other
lengths, sampling rates and noise levels, for the benchmarks and tests of record length."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import torch

from msam_torch.config.schema import DataConfig, load_config
from msam_torch.config.to_spec import to_spec
from msam_torch.data.loading import build_dataset
from msam_torch.data.systems import SYSTEMS, WITHHELD, measure


def withheld_records(length: float, faster: int, case: str = "msd_coulomb", noise: float = 0.01) -> tuple:
    """Training and held-out datasets of a withheld-effect ``case``, ``length`` times the bundled
    record's duration, sampled ``faster`` times faster, ``noise`` (a share of each measured state's
    standard deviation) added."""
    w = WITHHELD[case]
    spec = to_spec(load_config({"model": w.model}).model)
    rng = np.random.default_rng(0)
    out = []
    for name in (w.system, w.held_out):
        base = SYSTEMS[name]
        system = replace(base, samples=int(round((base.samples - 1) * length * faster)) + 1, t_end=base.t_end * length)
        sim = {k: v.numpy() for k, v in measure(system, rtol=1e-8, atol=1e-10).items()}
        measured = {k: sim[k] + (0 if k in system.inputs else noise * sim[k].std() * rng.standard_normal(sim[k].size))
                    for k in system.measured}
        out.append(build_dataset(sim["t"], measured, DataConfig(derivatives="savgol"), spec, {"source": name},
                                 torch.float64))
    return w, out


def finer_records(case: str, seconds: float, small: int, rows: int, noise: float, seed: int) -> dict:
    """Two records of a withheld-effect ``case`` over ``seconds``, as DataFrames keyed by their
    number of rows: ``small`` on the simulation grid and ``rows`` the same trajectory, finer
    (piecewise polynomials through the state and its derivatives), ``noise`` added to the state."""
    import pandas as pd
    from scipy.interpolate import BPoly

    effect = WITHHELD[case]
    system = replace(SYSTEMS[effect.system], t_end=seconds, samples=small)
    truth = {k: v.numpy() for k, v in measure(system).items()}
    rng = np.random.default_rng(seed)
    out = {}
    for n in (small, rows):
        if n == small:
            t, x = truth["t"], truth["x"]
        else:
            t = np.linspace(0.0, seconds, n)
            x = BPoly.from_derivatives(truth["t"], np.stack([truth["x"], truth["x_dot"], truth["x_ddot"]], -1))(t)
        u = system.inputs["u"](torch.from_numpy(t)).numpy()
        out[n] = pd.DataFrame({"t": t, "x": x + noise * x.std() * rng.standard_normal(n), "u": u})
    return out
