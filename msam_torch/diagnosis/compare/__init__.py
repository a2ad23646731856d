"""How a diagnosis judges its models: error measures, model comparison by free runs, parameter
intervals, confidence and the verdict."""
