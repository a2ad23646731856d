"""Runs from a config: the plan of strategies, ``adapt`` (Algorithm 1 on every state equation), results
and the adapted model as a module, batched trials, the distributed round robin, tracking and output
folders."""
