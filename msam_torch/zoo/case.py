"""One zoo case from an integer seed: a drawn system, a withheld effect (or none), units,
excitations, measured subset, noise; its truth, starting-model config and data frames.

``generate(seed)`` is deterministic. A draw that is not well posed (solver failure, unbounded or
non-positive trajectory, withheld effect below :data:`SHARE_FLOOR` of the dynamics) is drawn
again from the same random stream.
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import pandas as pd
import yaml

from msam_torch.model.spec import split_derivative
from msam_torch.zoo import excitation
from msam_torch.zoo.domains import DOMAINS
from msam_torch.zoo.effects import Combined, DrawnEffect
from msam_torch.zoo.simulate import dense_grid, effect_share, rms, signals, simulate, unabsorbed
from msam_torch.zoo.system import System, differences, factors, term_scale, term_value

NULL_SHARE, OUT_OF_CATALOGUE_SHARE = 0.25, 0.15  # probabilities of a null and of an out-of-catalogue case
NOISE_LEVELS = (0.0, 0.005, 0.01, 0.02, 0.05)  # fraction of each measured signal's standard deviation
SHARE_FLOOR = 0.05  # the withheld effect's unabsorbed share of its equation's rate, at least
SHARE_RANGE = (0.1, 0.3)  # the share a catalogued additive effect is sized to
SAMPLES = 2000
PERTURBATION = 0.2  # nominal parameters off by up to 20 %
ATTEMPTS = 40


@dataclass(frozen=True)
class Case:
    """A withheld-effect case: ``truth``, the starting-model ``config`` (the project's schema),
    the ``train`` and ``validation`` records (time column ``t`` + measured columns, case units),
    their noise-free versions with every state and the inputs the system feels (``clean``),
    and ``metadata`` (quantities, unit exponents, excitations, noise, measured subset)."""

    seed: int
    truth: dict
    config: dict
    train: pd.DataFrame
    validation: pd.DataFrame
    metadata: dict
    clean: dict = field(repr=False, default_factory=dict)
    system: System | None = field(repr=False, default=None)
    effect: DrawnEffect | Combined | None = field(repr=False, default=None)

    def write(self, folder: str | Path) -> Path:
        """``config.yaml``, ``train.csv``, ``validation.csv`` and ``truth.json`` in ``folder``."""
        folder = Path(folder)
        folder.mkdir(parents=True, exist_ok=True)
        self.train.to_csv(folder / "train.csv", index=False, float_format="%.12g")
        self.validation.to_csv(folder / "validation.csv", index=False, float_format="%.12g")
        (folder / "truth.json").write_text(json.dumps({"truth": self.truth, "metadata": self.metadata}, indent=1))
        path = folder / "config.yaml"
        path.write_text(yaml.safe_dump(self.config, sort_keys=False))
        return path

    def rates(self, frame: pd.DataFrame) -> dict:
        """The true right-hand side (case units) at the rows of a clean frame."""
        scale = self.metadata["scale"]
        values = {name: frame[name].to_numpy() / scale[name] for name in scale}
        values.update({u: frame[f"{u}_felt"].to_numpy() / scale[u] for u in self.system.inputs})
        rates = self.system.state_rates(values, self.effect)
        return {target: r * scale[split_derivative(target)[0]] for target, r in rates.items()}


def plan(seed: int, domains: tuple[str, ...] | None = None) -> tuple[str, str]:
    """The domain and kind ('null', 'out_of_catalogue' or 'catalogued') of ``seed``'s case, drawn
    from a stream of their own: redrawing an ill-posed system never changes them."""
    rng = np.random.default_rng([seed, 1])
    domain = str(rng.choice(sorted(domains or DOMAINS)))
    u = rng.random()
    kind = "null" if u < NULL_SHARE else "out_of_catalogue" if u < NULL_SHARE + OUT_OF_CATALOGUE_SHARE else "catalogued"
    return domain, kind


def generate(seed: int, domains: tuple[str, ...] | None = None, noise: float | None = None,
             samples: int = SAMPLES) -> Case:
    """The case of ``seed`` (``domains``: draw only from these; ``noise``: fix the noise level)."""
    domain, kind = plan(seed, domains)
    rng = np.random.default_rng(seed)
    builders = DOMAINS[domain]
    for _ in range(ATTEMPTS):
        system = builders[int(rng.integers(len(builders)))](rng)
        effects = [e for e in system.effects if e.catalogued == (kind == "catalogued")]
        if kind != "null" and not effects:
            continue  # an autonomous system has no input to distort
        specs = () if kind == "null" else (effects[int(rng.integers(len(effects)))],)
        case = draw(rng, seed, system, specs, noise, samples)
        if case is not None:
            return case
    raise RuntimeError(f"seed {seed}: no well-posed case in {ATTEMPTS} draws of domain {domain}")


def draw(rng, seed, system: System, specs: tuple, noise, samples) -> Case | None:
    """A case of ``system`` withholding the effects ``specs`` (none, one, or several catalogued
    power laws: :class:`~.effects.Combined`), or None when the draw is not well posed (each
    withheld effect's share at least :data:`SHARE_FLOOR`)."""
    noise = float(rng.choice(NOISE_LEVELS)) if noise is None else noise
    sample_rate = rng.uniform(20.0, 100.0) / system.period
    t = np.arange(samples) / sample_rate
    runs = []
    for label in ("train", "validation"):
        inputs, info = _inputs(rng, system, t, sample_rate)
        initial = _initial(rng, system)
        runs.append((label, inputs, initial, info))
    parts = [_size(rng, system, spec, runs[0], t) for spec in specs]
    if None in parts:
        return None
    effect = None if not parts else parts[0] if len(parts) == 1 else Combined(tuple(parts))
    records, shares = {}, {}
    for label, inputs, initial, info in runs:
        smooth = _smooth(info)
        felt = {k: (effect.shape_input(v) if effect is not None and k == effect.input else v) for k, v in inputs.items()}
        states = simulate(system, t, felt, initial, effect, smooth)
        if states is None or not _well_posed(system, states, simulate(system, t, inputs, initial, None, smooth)):
            return None
        values = signals(system, states, inputs, t)
        felt_values = signals(system, {}, felt, t)
        shares[label] = effect_share(system, values, effect, felt_values) if effect is not None else {}
        if len(parts) > 1 and label == "train":
            shares["parts"] = [max(effect_share(system, values, p).values()) for p in parts]
        records[label] = (t, values, felt_values, info)
    share = max(shares["train"].values(), default=0.0)
    if effect is not None and min([share, *shares.get("parts", [])]) < SHARE_FLOOR:
        return None
    return _case(rng, seed, system, effect, noise, records, share, shares)


def _inputs(rng, system: System, t, sample_rate) -> tuple[dict, dict]:
    dense = dense_grid(t)
    inputs, info = {}, {}
    for k, (u, (offset, amplitude)) in enumerate(system.drive.items()):
        kind = None if k == 0 else "multisine"  # the drive is random; further inputs (ambient) drift slowly
        e, info[u] = excitation.draw(rng, dense, sample_rate if k == 0 else 0.05 * sample_rate, kind)
        inputs[u] = offset + amplitude * e
    return inputs, info


def _initial(rng, system: System) -> dict:
    if not system.autonomous:
        return dict(system.initial)
    return {x: float(np.exp(rng.uniform(*np.log(system.initial_spread[x])))) for x in system.states}


def _well_posed(system: System, states: dict, reference: dict | None) -> bool:
    """Bounded (within 50x the range of the starting model's ``reference`` trajectory), varying,
    and positive where it must be."""
    if reference is None:
        return False
    for x, v in states.items():
        span = np.ptp(reference[x]) + abs(np.mean(reference[x]))
        if np.ptp(v) < 1e-6 * span or np.abs(v - np.mean(reference[x])).max() > 50 * span:
            return False
        if x in system.positive and v.min() <= 1e-3 * np.abs(v).max():
            return False
    return True


def _smooth(info: dict) -> frozenset:
    """The inputs interpolated by cubic splines: the multisines (steps and PRBS are held)."""
    return frozenset(u for u, d in info.items() if d["kind"] == "multisine")


def _size(rng, system: System, spec, run, t) -> DrawnEffect | None:
    """The drawn effect with its coefficient: additive terms sized to a share in :data:`SHARE_RANGE`
    of the rate along the starting model's trajectory; a multiplicative one equal to the starting
    component at the operating point; input nonlinearities scaled to the drive's amplitude."""
    if spec is None:
        return None
    gamma = float(rng.uniform(*spec.exponent))
    _, inputs, initial, info = run
    start = simulate(system, t, inputs, initial, None, _smooth(info))
    if start is None:
        return None
    values = signals(system, start, inputs, t)
    if spec.form in ("additive", "multiplicative"):
        smooth = 1e-3 * rms(term_value(spec.function, values))
        unit = DrawnEffect(spec, 1.0, gamma, smooth)
        eq = system.equation(spec.target)
        if spec.form == "multiplicative":
            theta = eq.theta[eq.terms.index(spec.component)]
            return replace(unit, coefficient=theta * abs(term_value(spec.function, system.initial)) ** -gamma)
        left = unabsorbed(eq, values, unit.contribution(spec.target, values))
        rate = system.state_rates(values)[spec.target]
        share = rng.uniform(*SHARE_RANGE)
        return replace(unit, coefficient=np.sign(spec.sign) * share * rms(rate) / max(rms(left), 1e-300))
    u = spec.component
    offset, amplitude = system.drive[u]
    width = amplitude * rng.uniform(*{"dead zone": (0.1, 0.3), "saturation": (0.3, 0.7), "backlash": (0.1, 0.3),
                                      "hysteresis": (0.2, 0.5)}[spec.form])
    return DrawnEffect(spec, width=width, input=u, centre=offset)


def _case(rng, seed, system: System, effect, noise, records, share, shares) -> Case:
    signal_names = list(system.states) + list(system.inputs)
    bases = sorted({split_derivative(s)[0] for s in signal_names})
    exponents = dict(zip(bases, (int(k) for k in rng.integers(-3, 4, len(bases)))))
    for pair in differences(t for e in system.equations for t in e.terms):  # a difference's signals share a unit
        first, second = (split_derivative(s)[0] for s in factors(pair)[0])
        exponents[second] = exponents[first]
    exponents = {s: exponents[split_derivative(s)[0]] for s in signal_names}  # x_dot in x's unit per second
    scale = {s: 10.0 ** k for s, k in exponents.items()}
    measured = list(system.measured[int(rng.integers(len(system.measured)))])
    frames, clean = {}, {}
    for label, (t, values, felt, info) in records.items():
        clean[label] = pd.DataFrame({"t": t, **{s: values[s] * scale[s] for s in signal_names},
                                     **{f"{u}_felt": felt[u] * scale[u] for u in system.inputs}})
        columns = {"t": clean[label]["t"].to_numpy()}
        for s in measured:
            x = clean[label][s].to_numpy()
            columns[s] = x + noise * x.std() * rng.standard_normal(x.size)
        columns.update({u: clean[label][u].to_numpy() for u in system.inputs})
        frames[label] = pd.DataFrame(columns)
    config, true_theta = _config(rng, system, scale, measured)
    truth = _truth(system, effect, scale, share, shares, true_theta)
    metadata = {"domain": system.domain, "system": system.name, "quantities": dict(system.quantities),
                "unit_exponents": exponents, "scale": scale, "noise": noise, "measured": measured,
                "sample_time": float(clean["train"]["t"].iloc[1]), "samples": len(frames["train"]),
                "excitation": {label: rec[3] for label, rec in records.items()}}
    return Case(seed, truth, config, frames["train"], frames["validation"], metadata, clean, system, effect)


def _config(rng, system: System, scale: dict, measured: list) -> tuple[dict, dict]:
    """Starting model in the case's units: true theta rescaled, then each off by up to 20 %."""
    parameters, equations, true_theta = {}, [], {}
    adjustments = [f"abs({x})" for x in system.states + tuple(differences(t for e in system.equations for t in e.terms))]
    for eq in system.equations:
        base = split_derivative(eq.target)[0]
        components, true_theta[eq.target] = [], {}
        for term, theta in zip(eq.terms, eq.theta):
            value = theta * scale[base] / term_scale(term, scale)
            name = f"p{len(parameters) + 1}"
            parameters[name] = float(value * (1 + rng.uniform(-PERTURBATION, PERTURBATION)))
            true_theta[eq.target][term] = float(value)
            driven = any(s in system.inputs for names in factors(term) for s in names)
            components.append({"term": term, "theta": name, **({"adjustable": False} if driven else {})})
        equations.append({"target": eq.target, "components": components, "adjustments": adjustments})
    config = {"model": {"states": list(system.states), "inputs": list(system.inputs), "parameters": parameters,
                        "equations": equations, "quantities": dict(system.quantities)},
              "data": {"file": "train.csv", "validation_file": "validation.csv", "time": "t", "derivatives": "savgol",
                       "columns": {s: s for s in measured + list(system.inputs)}}}
    return config, true_theta


def _truth(system: System, effect, scale: dict, share: float, shares: dict, true_theta: dict) -> dict:
    if effect is None:
        return {"kind": "null", "name": None, "share": 0.0, "theta": true_theta}
    if isinstance(effect, Combined):  # each part as a single effect's truth, with its own share
        parts = [_truth(system, p, scale, s, {**shares, "train": {}}, true_theta)
                 for p, s in zip(effect.parts, shares["parts"])]
        return {"kind": "several", "effects": parts, "share": share, "share_by_equation": shares["train"],
                "share_floor": SHARE_FLOOR, "theta": true_theta,
                "targets": sorted({t for p in parts for t in p["targets"]})}
    out = {"kind": "catalogued" if effect.effect.catalogued else "out_of_catalogue", "share": share,
           "share_by_equation": shares["train"], "share_floor": SHARE_FLOOR, "theta": true_theta, **effect.describe()}
    e = effect.effect
    if e.form in ("additive", "multiplicative"):
        base = split_derivative(e.target)[0]
        m_scale, f_scale = term_scale(e.component, scale), term_scale(e.function, scale)
        out["magnitude"] = float(effect.coefficient * scale[base] / m_scale / f_scale ** effect.gamma)
        out["magnitudes"] = {t: out["magnitude"] * e.weight(t) * scale[split_derivative(t)[0]] / scale[base]
                             for t in e.targets}  # the effect in each equation it enters
        out["smoothing"] = float(effect.smooth * f_scale)  # |f| -> sqrt(f^2 + s^2) for gamma < 0
        if e.exchange:  # ... - magnitude_exchange * e|e|^gamma
            out["exchange"] = e.exchange
            out["exchange_magnitude"] = float(effect.coefficient * scale[base] / scale[e.exchange] ** (1 + effect.gamma))
        out["targets"] = list(e.targets)
    else:
        out["targets"] = e.target.split(",")
        out["width"] = float(effect.width * scale[effect.input])
    return out
