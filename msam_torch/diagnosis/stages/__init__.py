"""The stages of a diagnosis: weak-form rows, localisation, residual structure, one equation's
diagnosis, the simulation-mode diagnosis and the pipeline over every equation."""
