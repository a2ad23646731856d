"""The zoo's first-principles systems, one drawing function per system, grouped by domain.

Each function draws physical parameters (SI units) from an ``np.random.Generator`` and returns a
:class:`~msam_torch.zoo.system.System` holding the true theta of its linear-in-theta equations
(Eq. 2) and the catalogue of effects that domain may withhold.
"""
from __future__ import annotations

import numpy as np

from msam_torch.zoo.effects import input_effects
from msam_torch.zoo.system import Effect, Equation, System


def log_uniform(rng: np.random.Generator, low: float, high: float) -> float:
    return float(np.exp(rng.uniform(np.log(low), np.log(high))))


def _oscillator(rng, domain, name, x, v, a, quantities, force) -> System:
    """``m a = -c v - k x + u``: a mass (inertia) on a spring (shaft) with viscous damping."""
    f0 = log_uniform(rng, 0.2, 5.0)  # resonance (Hz)
    w0 = 2 * np.pi * f0
    m = log_uniform(rng, 0.05, 20.0)
    zeta = rng.uniform(0.05, 0.3)
    k, c = m * w0**2, 2 * zeta * m * w0
    amplitude = log_uniform(rng, 0.005, 0.5)  # displacement scale (m or rad)
    eq = Equation(a, (v, x, "u"), (-c / m, -k / m, 1 / m))
    effects = (
        Effect("Coulomb friction", a, v, v, exponent=(-1.0, -1.0)),
        Effect("quadratic drag", a, v, v, exponent=(1.0, 1.0)),
        Effect("power-law damping", a, v, v, exponent=(0.3, 0.7)),
        Effect("cubic stiffness", a, x, x, exponent=(2.0, 2.0)),
        Effect("van der Pol-type damping", a, v, x, exponent=(2.0, 2.0)),
    ) + input_effects(("u",), (a,))
    return System(domain, name, (x, v), ("u",), (eq,), {x: quantities[0], v: quantities[1], "u": force},
                  {x: 0.0, v: 0.0}, {x: amplitude, v: amplitude * w0}, 1 / f0, effects, drive={"u": (0.0, k * amplitude)},
                  measured=((x, v), (x,)))


def translational(rng) -> System:
    return _oscillator(rng, "mechanical", "mass-spring-damper", "x", "x_dot", "x_ddot", ("position", "velocity"), "force")


def rotational(rng) -> System:
    return _oscillator(rng, "mechanical", "torsional inertia", "phi", "phi_dot", "phi_ddot",
                       ("angle", "angular_velocity"), "torque")


def two_bodies(rng) -> System:
    """``m1 x1'' = -k (x1 - x2) - c (x1' - x2') + u``, ``m2 x2'' = k (x1 - x2) + c (x1' - x2') - k2 x2 - c2 x2'``:
    a driven body coupled by a spring and a damper to a second one that stands on a stiffer spring
    (a quarter car); an effect between the bodies reads their relative displacement or velocity and
    acts on both (the reaction on the second body, times ``-m1/m2``)."""
    f0 = log_uniform(rng, 0.2, 5.0)
    w0 = 2 * np.pi * f0
    m1 = log_uniform(rng, 0.05, 20.0)
    m2 = m1 * log_uniform(rng, 0.3, 1.0)
    k = m1 * w0**2
    k2 = k * log_uniform(rng, 1.0, 4.0)
    c, c2 = 2 * rng.uniform(0.05, 0.3) * np.sqrt(k * m1), 2 * rng.uniform(0.02, 0.1) * np.sqrt(k2 * m2)
    amplitude = log_uniform(rng, 0.005, 0.5)  # relative displacement scale (m)
    equations = (Equation("x1_ddot", ("x1 - x2", "x1_dot - x2_dot", "u"), (-k / m1, -c / m1, 1 / m1)),
                 Equation("x2_ddot", ("x1 - x2", "x1_dot - x2_dot", "x2", "x2_dot"), (k / m2, c / m2, -k2 / m2, -c2 / m2)))
    between = (("x2_ddot", -m1 / m2),)
    effects = (
        Effect("Coulomb friction", "x1_ddot", "x1_dot - x2_dot", "x1_dot - x2_dot", exponent=(-1.0, -1.0), also=between),
        Effect("quadratic drag", "x1_ddot", "x1_dot - x2_dot", "x1_dot - x2_dot", exponent=(1.0, 1.0), also=between),
        Effect("cubic stiffness", "x1_ddot", "x1 - x2", "x1 - x2", exponent=(2.0, 2.0), also=between),
    ) + input_effects(("u",), ("x1_ddot",))
    x2 = amplitude * k / k2
    fastest = np.sqrt(np.abs(np.linalg.eigvals([[k / m1, -k / m1], [-k / m2, (k + k2) / m2]])).max())
    return System("mechanical", "two bodies", ("x1", "x1_dot", "x2", "x2_dot"), ("u",), equations,
                  {"x1": "position", "x1_dot": "velocity", "x2": "position", "x2_dot": "velocity", "u": "force"},
                  {"x1": 0.0, "x1_dot": 0.0, "x2": 0.0, "x2_dot": 0.0},
                  {"x1": amplitude, "x1_dot": amplitude * w0, "x2": x2, "x2_dot": x2 * w0}, 2 * np.pi / fastest, effects,
                  drive={"u": (0.0, k * amplitude)}, measured=(("x1", "x1_dot", "x2", "x2_dot"), ("x1", "x2")))


def dc_motor(rng) -> System:
    """``L i' = u - R i - K w``, ``J w' = K i - b w``: armature current and shaft speed."""
    tau_m = log_uniform(rng, 0.05, 2.0)
    tau_e = tau_m * rng.uniform(0.1, 0.5)
    resistance, k = log_uniform(rng, 0.5, 10.0), log_uniform(rng, 0.01, 0.5)
    inertia, inductance = tau_m * k**2 / resistance, tau_e * resistance
    b = inertia / tau_m * rng.uniform(0.05, 0.3)
    volts = log_uniform(rng, 1.0, 24.0)
    equations = (Equation("i_dot", ("i", "w", "u"), (-resistance / inductance, -k / inductance, 1 / inductance)),
                 Equation("w_dot", ("i", "w"), (k / inertia, -b / inertia)))
    effects = (Effect("Coulomb friction", "w_dot", "w", "w", exponent=(-1.0, -1.0)),
               Effect("quadratic drag", "w_dot", "w", "w", exponent=(1.0, 1.0))) + input_effects(("u",), ("i_dot",))
    return System("electromechanical", "DC motor", ("i", "w"), ("u",), equations,
                  {"i": "current", "w": "angular_velocity", "u": "voltage"}, {"i": 0.0, "w": 0.0},
                  {"i": volts / resistance, "w": volts / k}, 2 * np.pi * tau_m, effects, drive={"u": (0.0, volts)}, measured=(("i", "w"),))


def rlc(rng) -> System:
    """``C v' = i``, ``L i' = u - R i - v``: a series RLC circuit (capacitor voltage, loop current)."""
    f0 = log_uniform(rng, 5.0, 5e3)
    w0 = 2 * np.pi * f0
    capacitance = log_uniform(rng, 1e-7, 1e-3)
    inductance = 1 / (w0**2 * capacitance)
    resistance = 2 * rng.uniform(0.05, 0.4) * np.sqrt(inductance / capacitance)
    volts = log_uniform(rng, 0.5, 50.0)
    equations = (Equation("v_dot", ("i",), (1 / capacitance,)),
                 Equation("i_dot", ("v", "i", "u"), (-1 / inductance, -resistance / inductance, 1 / inductance)))
    effects = (Effect("non-linear resistance", "i_dot", "i", "i", exponent=(1.0, 2.0)),) + input_effects(("u",), ("i_dot",))
    return System("electrical", "series RLC", ("v", "i"), ("u",), equations,
                  {"v": "voltage", "i": "current", "u": "voltage"}, {"v": 0.0, "i": 0.0}, {"v": volts, "i": volts * np.sqrt(capacitance / inductance)}, 1 / f0, effects,
                  drive={"u": (0.0, volts)}, measured=(("v", "i"),))


def rlc_network(rng) -> System:
    """Two capacitor nodes joined by an inductor: ``C1 v1' = (u - v1)/R1 - i``, ``L i' = (v1 - v2) - R i``,
    ``C2 v2' = i - v2/R2``; the link's resistance may be non-linear, or its inductance saturate (the
    current's rate on the voltage across it, ``v1 - v2``, growing with ``|i|``)."""
    f0 = log_uniform(rng, 5.0, 5e3)
    c1 = log_uniform(rng, 1e-7, 1e-3)
    c2 = c1 * log_uniform(rng, 0.5, 2.0)
    inductance = (c1 + c2) / (c1 * c2) / (2 * np.pi * f0) ** 2
    impedance = np.sqrt(inductance / c1)
    resistance = 2 * rng.uniform(0.05, 0.4) * impedance
    r1, r2 = impedance * log_uniform(rng, 0.5, 2.0), impedance * log_uniform(rng, 0.5, 5.0)
    volts = log_uniform(rng, 0.5, 50.0)
    equations = (Equation("v1_dot", ("u", "v1", "i"), (1 / (r1 * c1), -1 / (r1 * c1), -1 / c1)),
                 Equation("i_dot", ("v1 - v2", "i"), (1 / inductance, -resistance / inductance)),
                 Equation("v2_dot", ("i", "v2"), (1 / c2, -1 / (r2 * c2))))
    effects = (Effect("non-linear resistance", "i_dot", "i", "i", exponent=(1.0, 2.0)),
               Effect("saturating inductance", "i_dot", "v1 - v2", "i", exponent=(0.5, 2.0), sign=1.0),
               ) + input_effects(("u",), ("v1_dot",))
    return System("electrical", "RLC network", ("v1", "i", "v2"), ("u",), equations,
                  {"v1": "voltage", "i": "current", "v2": "voltage", "u": "voltage"}, {"v1": 0.0, "i": 0.0, "v2": 0.0},
                  {"v1": volts, "i": volts / impedance, "v2": volts}, 1 / f0, effects, drive={"u": (0.0, volts)},
                  measured=(("v1", "i", "v2"),))


def _outflow(rng):
    """Operating level h0 (m) and the linear outflow rate (1/s) near it."""
    return log_uniform(rng, 0.1, 2.0), 1 / log_uniform(rng, 5.0, 500.0)


def tank(rng) -> System:
    """``h' = -a h + b u``: a tank filled by a pump, emptied through an outlet (linear outflow);
    the truth may drain by Torricelli's law ``-k sqrt(h)``."""
    h0, rate = _outflow(rng)
    gain = log_uniform(rng, 0.01, 1.0)  # level rise rate per pump volt (m/s/V)
    volts = rate * h0 / gain
    eq = Equation("h_dot", ("h", "u"), (-rate, gain))
    effects = (Effect("Torricelli outflow", "h_dot", "h", "h", form="multiplicative", exponent=(-0.5, -0.5)),
               ) + input_effects(("u",), ("h_dot",))
    return System("hydraulic", "tank", ("h",), ("u",), (eq,), {"h": "level", "u": "voltage"}, {"h": h0}, {"h": h0},
                  2 * np.pi / rate, effects, drive={"u": (volts, 0.8 * volts)},
                  positive=("h",), measured=(("h",),))


def cascaded_tanks(rng) -> System:
    """``h1' = -a1 h1 + b u``, ``h2' = a2 h1 - a3 h2``: the upper tank drains into the lower one."""
    h0, rate = _outflow(rng)
    gain = log_uniform(rng, 0.01, 1.0)
    rate1 = rate * rng.uniform(0.5, 2.0)
    areas = rng.uniform(0.5, 2.0)  # upper / lower tank area
    volts = rate1 * h0 / gain
    equations = (Equation("h1_dot", ("h1", "u"), (-rate1, gain)),
                 Equation("h2_dot", ("h1", "h2"), (rate1 * areas, -rate)))
    effects = (Effect("Torricelli outflow", "h2_dot", "h2", "h2", form="multiplicative", exponent=(-0.5, -0.5)),
               ) + input_effects(("u",), ("h1_dot",))
    h2 = rate1 * areas * h0 / rate
    return System("hydraulic", "cascaded tanks", ("h1", "h2"), ("u",), equations,
                  {"h1": "level", "h2": "level", "u": "voltage"}, {"h1": h0, "h2": h2}, {"h1": h0, "h2": h2}, 2 * np.pi / min(rate, rate1),
                  effects, drive={"u": (volts, 0.8 * volts)}, positive=("h1", "h2"),
                  measured=(("h1", "h2"),))


def connected_tanks(rng) -> System:
    """``h1' = -a1 (h1 - h2) + b u``, ``h2' = a2 (h1 - h2) - a3 h2``: a pumped tank joined at its bottom
    to a second one that drains through an outlet; the pipe between them may follow Torricelli's law in
    ``h1 - h2`` (in both tanks, the second's rate times the area ratio), the outlet too."""
    h0, rate = _outflow(rng)  # the second tank's operating level and outflow rate
    gain = log_uniform(rng, 0.01, 1.0)
    rate1, areas = rate * rng.uniform(0.5, 2.0), rng.uniform(0.5, 2.0)  # pipe rate of tank 1, area 1 / area 2
    difference = rate * h0 / (rate1 * areas)  # h1 - h2 at the operating point
    volts = rate1 * difference / gain
    equations = (Equation("h1_dot", ("h1 - h2", "u"), (-rate1, gain)),
                 Equation("h2_dot", ("h1 - h2", "h2"), (rate1 * areas, -rate)))
    effects = (Effect("Torricelli outflow", "h1_dot", "h1 - h2", "h1 - h2", form="multiplicative", exponent=(-0.5, -0.5),
                      also=(("h2_dot", -areas),)),
               Effect("Torricelli outflow", "h2_dot", "h2", "h2", form="multiplicative", exponent=(-0.5, -0.5)),
               ) + input_effects(("u",), ("h1_dot",))
    levels = {"h1": h0 + difference, "h2": h0}
    fastest = np.abs(np.linalg.eigvals([[-rate1, rate1], [rate1 * areas, -rate1 * areas - rate]])).max()
    return System("hydraulic", "connected tanks", ("h1", "h2"), ("u",), equations,
                  {"h1": "level", "h2": "level", "u": "voltage"}, levels, levels, 2 * np.pi / fastest,
                  effects, drive={"u": (volts, 0.8 * volts)}, positive=("h1", "h2"), measured=(("h1", "h2"),))


def heated_body(rng) -> System:
    """``C T' = -hA (T - Ta) + u``: a body heated by ``u`` (W) in air at a measured ambient ``Ta``
    (K); the truth may also radiate, ``-eps sigma A (T^4 - Ta^4)``."""
    tau = log_uniform(rng, 10.0, 2000.0)
    capacity = log_uniform(rng, 10.0, 1e4)  # J/K
    ha = capacity / tau
    rise = rng.uniform(50.0, 300.0)  # mean temperature rise (K)
    watts = ha * rise
    eq = Equation("T_dot", ("T", "Ta", "u"), (-ha / capacity, ha / capacity, 1 / capacity))
    effects = (Effect("radiation", "T_dot", "T", "T", exponent=(3.0, 3.0), exchange="Ta"),
               ) + input_effects(("u",), ("T_dot",))
    return System("thermal", "heated body", ("T",), ("u", "Ta"), (eq,),
                  {"T": "temperature", "Ta": "temperature", "u": "power"}, {"T": 293.0 + rise}, {"T": 293.0 + rise}, 2 * np.pi * tau,
                  effects, drive={"u": (watts, 0.8 * watts), "Ta": (rng.uniform(270.0, 310.0), 5.0)},
                  positive=("T",), measured=(("T",),))


def predator_prey(rng) -> System:
    """Lotka-Volterra: ``prey' = a prey - b prey pred``, ``pred' = c prey pred - d pred``; the truth
    may limit the prey's growth (logistic, ``-a/K prey^2``). Autonomous: excited by its start."""
    a, d = log_uniform(rng, 0.2, 2.0), log_uniform(rng, 0.2, 2.0)
    prey0, pred0 = log_uniform(rng, 10.0, 1e4), log_uniform(rng, 10.0, 1e4)
    b, c = a / pred0, d / prey0  # equilibrium at (prey0, pred0)
    equations = (Equation("prey_dot", ("prey", "prey*pred"), (a, -b)),
                 Equation("pred_dot", ("prey*pred", "pred"), (c, -d)))
    effects = (Effect("logistic self-limitation", "prey_dot", "prey", "prey", exponent=(1.0, 1.0)),)
    return System("population_kinetics", "predator-prey", ("prey", "pred"), (), equations,
                  {"prey": "population", "pred": "population"}, {"prey": prey0, "pred": pred0},
                  {"prey": prey0, "pred": pred0}, 2 * np.pi / np.sqrt(a * d), effects, positive=("prey", "pred"), measured=(("prey", "pred"),),
                  autonomous=True, initial_spread={"prey": (0.3 * prey0, 2.0 * prey0), "pred": (0.3 * pred0, 2.0 * pred0)})


def chemostat(rng) -> System:
    """A continuously stirred reactor: ``c' = D (u - c) - k c`` (feed concentration ``u``, first-order
    reaction); the truth's reaction may be of higher mass-action order (``-k2 c^2``)."""
    dilution = log_uniform(rng, 0.01, 1.0)
    k = dilution * rng.uniform(0.2, 2.0)
    feed = log_uniform(rng, 0.1, 10.0)  # mol/l
    eq = Equation("c_dot", ("u", "c"), (dilution, -(dilution + k)))
    effects = (Effect("mass-action order", "c_dot", "c", "c", exponent=(1.0, 1.0)),) + input_effects(("u",), ("c_dot",))
    return System("population_kinetics", "chemostat", ("c",), ("u",), (eq,),
                  {"c": "concentration", "u": "concentration"}, {"c": dilution * feed / (dilution + k)},
                  {"c": dilution * feed / (dilution + k)}, 2 * np.pi / (dilution + k), effects, drive={"u": (feed, 0.8 * feed)}, positive=("c",),
                  measured=(("c",),))


DOMAINS: dict[str, tuple] = {
    "mechanical": (translational, rotational, two_bodies),
    "electromechanical": (dc_motor,),
    "electrical": (rlc, rlc_network),
    "hydraulic": (tank, cascaded_tanks, connected_tanks),
    "thermal": (heated_body,),
    "population_kinetics": (predator_prey, chemostat),
}
