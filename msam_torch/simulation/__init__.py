"""Simulation: the one ODE model of Eq. 9 (:mod:`.ode`), the one ``simulate()`` (:mod:`.solver`),
records (:mod:`.record`) and their set-up from a config (:mod:`.configured`), exact forward-mode
sensitivities (:mod:`.sensitivities`), the simulation evaluator of Algorithm 1 (:mod:`.evaluator`),
free runs (:mod:`.free_run`) and per-equation models for the diagnosis (:mod:`.equations`)."""
